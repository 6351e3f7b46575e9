"""In-memory scene: posed views with images and optional masks, split into train and test."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from go_core.camera import Camera


@dataclass
class View:
    """One posed photo. ``image`` is float32 [H, W, 3] sRGB in [0, 1] (straight, not premultiplied);
    ``mask`` is float32 [H, W] in [0, 1] (fractional coverage allowed) or None when not given."""

    camera: Camera
    image: np.ndarray = field(repr=False)
    mask: np.ndarray | None = field(default=None, repr=False)
    source: Path | None = None  # the image file it came from
    mask_source: Path | None = None  # the mask file, when the mask came from its own file (else None)

    @property
    def name(self) -> str:
        return self.camera.name


@dataclass
class Scene:
    """A scene folder read into memory. ``format`` is "nerf" (transforms_*.json) or "colmap"."""

    root: Path
    format: str
    train: list[View]
    test: list[View]
    split_source: str = ""  # where the train/test split came from (e.g. "sparse_4.txt", "transforms_*.json")
    original_max_side: int = 0  # longest image side before a max_size downscale (0: not recorded)

    @property
    def train_cameras(self) -> list[Camera]:
        return [v.camera for v in self.train]

    @property
    def test_cameras(self) -> list[Camera]:
        return [v.camera for v in self.test]
