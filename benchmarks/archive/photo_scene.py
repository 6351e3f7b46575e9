"""Build a scene folder (NeRF-synthetic layout, as shared/data/real) from a photo set with reference poses.

A photo set (shared/data/photos/<name>) holds ``images/NAME.jpg`` and, for evaluation only,
``reference/masks/NAME.png`` and ``reference/transforms.json`` (OpenGL camera-to-world poses, intrinsics of
the photos, ``train_views``: the 4 sparse training picks). This writes ``transforms_train.json`` (the 4
``train_views``), ``transforms_test.json`` (every other photo) and RGBA PNGs (alpha = the binary mask) at a
working resolution: long side ``long_side`` px, the photo resized with Lanczos, the mask area-downscaled and
thresholded at 0.5 (as the converter made shared/data/real), intrinsics scaled to match.

Benchmarks only: the product never reads ``reference/``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from PIL import Image

__all__ = ["build_photo_scene"]


def _scaled_intrinsics(meta: dict, scale_x: float, scale_y: float, w: int, h: int) -> dict:
    """fl_x/fl_y/cx/cy for an image resized from meta's (w, h) to (w, h) here (pixel-corner convention)."""
    fx, fy = meta["fl_x"] * scale_x, meta["fl_y"] * scale_y
    return {
        "fl_x": fx,
        "fl_y": fy,
        "cx": meta["cx"] * scale_x,
        "cy": meta["cy"] * scale_y,
        "w": w,
        "h": h,
        "camera_angle_x": float(2 * np.arctan(w / (2 * fx))),
        "camera_angle_y": float(2 * np.arctan(h / (2 * fy))),
    }


def _write_view(src: Path, name: str, out: Path, rel: str, size: tuple[int, int]) -> None:
    """One RGBA PNG: the photo resized to ``size`` (Lanczos) with its mask as alpha (area filter, > 0.5)."""
    photo = Image.open(src / "images" / f"{name}.jpg").convert("RGB").resize(size, Image.LANCZOS)
    mask = Image.open(src / "reference" / "masks" / f"{name}.png").convert("L").resize(size, Image.BOX)
    alpha = np.where(np.asarray(mask, np.float32) > 127.5, 255, 0).astype(np.uint8)
    rgba = np.concatenate([np.asarray(photo), alpha[..., None]], axis=-1)
    path = out / f"{rel}.png"
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(rgba, "RGBA").save(path)


def build_photo_scene(src: Path, out: Path, long_side: int = 512) -> Path:
    """Write the scene folder for photo set ``src`` into ``out`` (skipped when its test split exists);
    returns ``out``."""
    src, out = Path(src), Path(out)
    if (out / "transforms_test.json").is_file():
        return out
    meta = json.loads((src / "reference" / "transforms.json").read_text())
    w0, h0 = int(meta["w"]), int(meta["h"])
    scale = long_side / max(w0, h0)
    w, h = max(1, round(w0 * scale)), max(1, round(h0 * scale))
    intr = _scaled_intrinsics(meta, w / w0, h / h0, w, h)
    train_names = list(meta["train_views"])
    splits: dict[str, list[dict]] = {"train": [], "test": []}
    for frame in meta["frames"]:
        name = Path(frame["file_path"]).name
        split = "train" if name in train_names else "test"
        rel = f"{split}/r_{len(splits[split])}"
        _write_view(src, name, out, rel, (w, h))
        splits[split].append(
            {"file_path": f"./{rel}", "source_image": name, "transform_matrix": frame["transform_matrix"]}
        )
    order = {n: i for i, n in enumerate(train_names)}
    splits["train"].sort(key=lambda f: order[f["source_image"]])
    for split, frames in splits.items():
        doc = {**intr, "frames": frames, "source": str(src), "working_long_side": long_side}
        (out / f"transforms_{split}.json").write_text(json.dumps(doc, indent=1) + "\n")
    return out
