"""Round trip of the compressed export formats through an independent reader (npm spz-js, run by node):
how far each attribute moves, and what the read-back model renders like next to the original.

    cd js && npm ci && cd ..
    python benchmarks/archive/export_roundtrip.py go-example/basket \
        --json benchmarks/results/export_roundtrip.json

For the scene's final model (the export step's ``point_cloud.ply``), writes ``.spz`` and SuperSplat
``.compressed.ply``, reads each back with spz-js, and reports per attribute the largest and mean absolute
error (positions against the format's quantisation step), then renders original and read-back model from
every test camera (go-pipeline's rasterizer) and compares both against the ground truth (PSNR, masked).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository: tests/_spz_reader.py
from tests._spz_reader import (  # noqa: E402
    attribute_errors,
    compare,
    read_back,
    reader_missing,
    renders,
    written_order,
)

SUFFIXES = {"spz": ".spz", "compressed_ply": ".compressed.ply"}


def ground_truth(view, background: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The test photo on the render background (composited with its mask) and the object's pixels."""
    img = torch.as_tensor(view.image[..., :3], dtype=torch.float64)
    if view.mask is None:
        return img, torch.ones(img.shape[:2], dtype=torch.bool)
    m = torch.as_tensor(view.mask, dtype=torch.float64)[..., None]
    return img * m + background.double() * (1 - m), m[..., 0] > 0.5


def spz_range_report(g) -> dict[str, int]:
    """How many Gaussians have a value beyond what .spz can hold (clamped by any writer): log scales outside
    [-10, 5.94], base colours outside [0, 1] (|f_dc| > 0.5 / 0.15), higher SH outside [-1, 1)."""
    from go_core.formats.spz import COLOR_SCALE

    ls, dc, rest = g.log_scales.double(), g.sh[:, 0].double(), g.sh[:, 1:].double()
    return {
        "log_scale": int(((ls < -10) | (ls > 255 / 16 - 10)).any(1).sum()),
        "sh_dc": int((dc.abs() > 0.5 / COLOR_SCALE).any(1).sum()),
        "sh_rest": int((rest.abs() > 1).flatten(1).any(1).sum()),
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("scene", type=Path)
    p.add_argument("--workdir", type=Path, default=None)
    p.add_argument("--json", type=Path, default=None)
    args = p.parse_args(argv)
    why = reader_missing()
    if why:
        print(f"error: {why}", file=sys.stderr)
        return 2
    from go_core import artifacts as art
    from go_core.formats import encode
    from go_core.formats.spz import position_step
    from go_core.ply import load_ply
    from go_pipeline import store

    wd = store.workdir_for(args.scene, args.workdir)
    g = load_ply(store.artifact_dir(wd, "export") / art.POINT_CLOUD.file)
    scene = art.read_scene(store.artifact_dir(wd, "scene"))
    bg = torch.ones(3, dtype=torch.float32)
    cams = [v.camera for v in scene.test]
    gt, masks = zip(*(ground_truth(v, bg) for v in scene.test), strict=True)
    original = renders(g, cams, bg)
    result = {"scene": str(args.scene), "gaussians": len(g), "test_views": len(cams)}
    result["original_vs_gt"] = compare(original, list(gt), list(masks))
    ply_bytes = (store.artifact_dir(wd, "export") / art.POINT_CLOUD.file).stat().st_size
    with tempfile.TemporaryDirectory(prefix="go-roundtrip-") as tmp:
        for fmt, suffix in SUFFIXES.items():
            path = Path(tmp) / f"model{suffix}"
            path.write_bytes(encode(g, fmt))
            back = read_back(path)
            decoded = renders(back, cams, bg)
            result[fmt] = {
                "bytes": path.stat().st_size,
                "ply_bytes": ply_bytes,
                "gaussians_read": len(back),
                "errors": attribute_errors(g, back, written_order(g, fmt)),
                "readback_vs_gt": compare(decoded, list(gt), list(masks)),
                "readback_vs_original_render": compare(decoded, original, list(masks)),
            }
    result["spz"]["position_step"] = position_step()
    result["spz"]["outside_the_format_range"] = spz_range_report(g)
    text = json.dumps(result, indent=2, sort_keys=True)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(text + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
