"""`go-pipeline compare A.png B.png`: PSNR / SSIM / LPIPS (vgg, alex) of two images of the same size."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from go_core.errors import GoError


def load_rgb(path: Path, background: float = 1.0) -> np.ndarray:
    """float32 [H,W,3] in [0, 1] (8/16-bit, float, EXR via go_core.io.images); alpha is composited over
    ``background`` (white, the paper protocol)."""
    from go_core.io.images import read_image, split_rgb_alpha

    rgb, alpha = split_rgb_alpha(read_image(path))
    if alpha is not None:
        a = np.clip(alpha, 0.0, 1.0)[..., None]
        rgb = rgb * a + background * (1.0 - a)
    return np.clip(rgb, 0.0, 1.0).astype(np.float32)


def compare_images(a: np.ndarray, b: np.ndarray, nets: tuple[str, ...] = ("vgg", "alex")) -> dict:
    from go_core.metrics.evaluate import MetricSuite

    suite = MetricSuite.load(nets)
    out = suite.evaluate(a, b)
    out["lpips_status"] = suite.status()
    return out


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("compare", help="PSNR / SSIM / LPIPS of two images")
    p.add_argument("image_a", type=Path)
    p.add_argument("image_b", type=Path)
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    a, b = load_rgb(args.image_a), load_rgb(args.image_b)
    if a.shape != b.shape:
        raise GoError(
            f"image sizes differ: {a.shape[1]}x{a.shape[0]} vs {b.shape[1]}x{b.shape[0]}", args.image_b
        )
    res = compare_images(a, b)
    if args.json:
        print(json.dumps(res, indent=2, sort_keys=True))
        return 0

    def fmt(v, spec):
        return "n/a" if v is None else format(v, spec)

    print(
        f"PSNR        {fmt(res['psnr'], '.3f')} dB"
        if res["psnr"] is not None
        else "PSNR        inf (identical)"
    )
    print(f"SSIM        {fmt(res['ssim'], '.4f')}")
    print(f"LPIPS-vgg   {fmt(res['lpips_vgg'], '.4f')}   (LPIPS* = {fmt(res['lpips_star'], '.2f')})")
    print(f"LPIPS-alex  {fmt(res['lpips_alex'], '.4f')}")
    for net, status in res["lpips_status"].items():
        if status != "ok":
            print(f"note: LPIPS-{net} {status}")
    return 0
