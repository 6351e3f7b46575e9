"""Monocular depth prior from a LOCAL transformers checkpoint folder (DPT, Depth-Anything, ...).

These models predict relative inverse depth (disparity: larger = closer) up to an unknown shift and scale,
which is exactly what the shift/scale-invariant depth loss (go_core.coarse.losses.depth_loss) needs.
Nothing is downloaded: ``from_pretrained`` is called with ``local_files_only=True``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from go_core import artifact_files as artifacts
from go_core.errors import MissingWeightsError
from go_core.io.images import to_uint8


@dataclass
class DepthEstimator:
    """Wraps ``AutoModelForDepthEstimation`` + its image processor from ``path``."""

    path: Path
    device: str = "cpu"

    def __post_init__(self) -> None:
        self.path = Path(self.path)
        if not (self.path / "config.json").is_file():
            raise MissingWeightsError(
                "no transformers depth model here (config.json missing); point depth.model_path at a local "
                "DPT / Depth-Anything checkpoint folder",
                path=self.path,
            )
        from transformers import AutoImageProcessor, AutoModelForDepthEstimation

        self.processor = AutoImageProcessor.from_pretrained(str(self.path), local_files_only=True)
        self.model = AutoModelForDepthEstimation.from_pretrained(str(self.path), local_files_only=True)
        self.model.eval().to(self.device)

    @property
    def name(self) -> str:
        return f"{self.model.config.model_type}:{self.path.name}"

    @torch.no_grad()
    def __call__(self, image: np.ndarray) -> np.ndarray:
        """Disparity [H,W] float32 for an RGB float image [H,W,3] in [0,1] (resized back bicubically)."""
        h, w = image.shape[:2]
        u8 = to_uint8(image)
        inputs = self.processor(images=u8, return_tensors="pt")
        inputs = {k: v.to(self.device) for k, v in inputs.items()}
        pred = self.model(**inputs).predicted_depth  # [1,h',w']
        pred = torch.nn.functional.interpolate(
            pred[:, None].float(), size=(h, w), mode="bicubic", align_corners=False
        )
        return pred[0, 0].cpu().numpy().astype(np.float32)


DEPTH_FILE = artifacts.DEPTH.file
DEPTH_JSON = artifacts.DEPTH_INFO.file


def save_depth_priors(out_dir: str | Path, disparities: list[np.ndarray]) -> Path:
    """``depth.npz`` with ``train_000``, ... float32 disparity maps (empty when the step was skipped)."""
    from go_core.scene.artifact import write_npz_deterministic

    arrays = {f"train_{i:03d}": np.asarray(d, np.float32) for i, d in enumerate(disparities)}
    return write_npz_deterministic(Path(out_dir) / DEPTH_FILE, arrays)


def load_depth_priors(depth_dir: str | Path | None) -> list[np.ndarray] | None:
    """The depth step's disparity maps in training-view order, or None when it was skipped / absent."""
    if depth_dir is None:
        return None
    path = Path(depth_dir) / DEPTH_FILE
    if not path.is_file():
        return None
    with np.load(path, allow_pickle=False) as data:
        names = sorted(n for n in data.files if n.startswith("train_"))
        maps = [data[n].astype(np.float32) for n in names]
    return maps or None
