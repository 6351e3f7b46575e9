"""Object masks for the training views: validate provided ones, or compute them.

* provided: a mask file or the image's alpha (read by the scene step); checked for shape, range, finiteness
  and a non-empty foreground;
* ``grabcut``: OpenCV GrabCut initialised with the image border as sure background (the object is assumed
  to be inside, away from the border, as in object-centric captures);
* ``onnx``: a salient-object segmentation model (u2netp from the weights cache, or an ISNet / U²-Net ONNX
  export from a LOCAL file), run with onnxruntime on CPU. The model takes one [1,3,S,S] float image and its
  first output is a saliency map [1,1,s,s] (any s); it is min-max normalised and resized back to the image.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from go_core import artifact_files as artifacts
from go_core.errors import MissingWeightsError, SceneError, first_line
from go_core.io.images import to_uint8

NORMALISATIONS = {
    "imagenet": ((0.485, 0.456, 0.406), (0.229, 0.224, 0.225)),  # U²-Net
    "isnet": ((0.5, 0.5, 0.5), (1.0, 1.0, 1.0)),  # DIS / ISNet
}


def validate_mask(
    mask: np.ndarray, image_shape: tuple[int, int], name: str, min_fraction: float = 1e-4
) -> None:
    """Raise ``SceneError`` (one line naming the view) if a provided mask is unusable."""
    if mask.ndim != 2 or tuple(mask.shape) != tuple(image_shape):
        raise SceneError(f"mask is {mask.shape}, image is {tuple(image_shape)}", path=name)
    if not np.isfinite(mask).all():
        raise SceneError("mask has non-finite values", path=name)
    if mask.min() < 0.0 or mask.max() > 1.0:
        raise SceneError(
            f"mask values must be in [0, 1], got [{mask.min():.3g}, {mask.max():.3g}]", path=name
        )
    fg = float((mask > 0.5).mean())
    if fg < min_fraction:
        raise SceneError("mask is empty (no pixel above 0.5): the object is not masked", path=name)


def grabcut_mask(image: np.ndarray, iterations: int = 5, border: float = 0.03) -> np.ndarray:
    """GrabCut foreground [H,W] float32 in {0,1}; the outer ``border`` fraction (≥ 1 px) is background."""
    h, w = image.shape[:2]
    bgr = cv2.cvtColor(to_uint8(image), cv2.COLOR_RGB2BGR)
    bx, by = max(1, round(border * w)), max(1, round(border * h))
    rect = (bx, by, w - 2 * bx, h - 2 * by)
    mask = np.zeros((h, w), np.uint8)
    bgd = np.zeros((1, 65), np.float64)
    fgd = np.zeros((1, 65), np.float64)
    cv2.setRNGSeed(0)
    cv2.grabCut(bgr, mask, rect, bgd, fgd, int(iterations), cv2.GC_INIT_WITH_RECT)
    fg = (mask == cv2.GC_FGD) | (mask == cv2.GC_PR_FGD)
    return fg.astype(np.float32)


@dataclass
class OnnxSegmenter:
    """A salient-object ONNX model (onnxruntime, CPU): ``u2netp`` from the weights cache (the auto masks,
    go_core.scene.salient_weights) or a user's ISNet / U²-Net export from a local path.

    Pre- and post-processing are rembg's (the reference runtime of these exports, and U²-Net's own
    ``ToTensorLab``): the RGB image is resized to the model's square input with Pillow's Lanczos filter,
    divided by its maximum (not by 255), normalised by mean/std; the first output (U²-Net's fused ``d1``)
    is min-max normalised over the map and resized back with Lanczos."""

    path: Path
    normalisation: str = "imagenet"
    size: int = 0  # input side; 0 = read from the model (fallback 320)
    threads: int = 2

    def __post_init__(self) -> None:
        self.path = Path(self.path)
        if not self.path.is_file():
            raise MissingWeightsError(
                "ONNX salient-object model not found; export ISNet/U2-Net to ONNX and set mask.onnx_model",
                path=self.path,
            )
        if self.normalisation not in NORMALISATIONS:
            raise ValueError(f"normalisation must be one of {sorted(NORMALISATIONS)}")
        import onnxruntime as ort

        opts = ort.SessionOptions()
        opts.intra_op_num_threads = self.threads
        opts.inter_op_num_threads = 1
        try:
            self.session = ort.InferenceSession(str(self.path), opts, providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime raises its own exception types for unreadable models
            raise MissingWeightsError(f"not a loadable ONNX model ({first_line(exc)})", self.path) from exc
        inp = self.session.get_inputs()[0]
        self.input_name = inp.name
        if not self.size:
            dims = [d for d in inp.shape[2:] if isinstance(d, int)]
            self.size = int(dims[0]) if dims else 320

    def model_input(self, image: np.ndarray) -> np.ndarray:
        """[1,3,S,S] float32: Lanczos resize, divide by the maximum, mean/std normalisation."""
        from PIL import Image

        side = (self.size, self.size)
        rgb = Image.fromarray(to_uint8(image)[..., :3]).resize(side, Image.Resampling.LANCZOS)
        x = np.asarray(rgb, np.float64)
        x = x / max(float(x.max()), 1e-6)
        mean, std = NORMALISATIONS[self.normalisation]
        x = (x - np.asarray(mean)) / np.asarray(std)
        return x.transpose(2, 0, 1)[None].astype(np.float32)

    def raw(self, image: np.ndarray) -> np.ndarray:
        """The model's min-max normalised saliency at its own resolution [s, s] float32."""
        out = self.session.run(None, {self.input_name: self.model_input(image)})[0]
        sal = np.asarray(out, np.float32).reshape(out.shape[-2], out.shape[-1])
        lo, hi = float(sal.min()), float(sal.max())
        return (sal - lo) / (hi - lo) if hi > lo else np.zeros_like(sal)

    def __call__(self, image: np.ndarray) -> np.ndarray:
        """Saliency [H,W] float32 in [0, 1] of an RGB image (uint8, or float in [0, 1])."""
        from PIL import Image

        h, w = image.shape[:2]
        sal = Image.fromarray(self.raw(image)).resize((w, h), Image.Resampling.LANCZOS)
        return np.clip(np.asarray(sal, np.float32), 0.0, 1.0)


def mask_stats(mask: np.ndarray) -> dict:
    return {
        "foreground_fraction": round(float((mask > 0.5).mean()), 6),
        "fractional": bool(((mask > 0) & (mask < 1)).any()),
    }


# Artifact IO ---------------------------------------------------------------------------------------------
MASKS_FILE = artifacts.MASKS.file


def save_masks(out_dir: str | Path, masks: list[np.ndarray]) -> Path:
    """``masks.npz`` with ``train_000``, ``train_001``, ... float32 [H,W] (deterministic bytes)."""
    from go_core.scene.artifact import write_npz_deterministic

    arrays = {f"train_{i:03d}": np.asarray(m, np.float32) for i, m in enumerate(masks)}
    return write_npz_deterministic(Path(out_dir) / MASKS_FILE, arrays)


def load_masks(mask_dir: str | Path, count: int | None = None) -> list[np.ndarray]:
    """The training masks written by the mask step, in training-view order."""
    path = Path(mask_dir) / MASKS_FILE
    if not path.is_file():
        raise SceneError("masks are missing (run the `mask` step first)", path=path)
    with np.load(path, allow_pickle=False) as data:
        names = sorted(n for n in data.files if n.startswith("train_"))
        masks = [data[n].astype(np.float32) for n in names]
    if count is not None and len(masks) != count:
        raise SceneError(f"{len(masks)} masks for {count} training views (stale mask artifact?)", path=path)
    return masks
