"""Reading what the repair steps need from upstream artifacts, and rendering helpers.

* training views: the ``scene`` artifact's training views with the ``mask`` step's masks
  (``masks.npz``; falls back to the scene's own masks), as ``go_core.training.TrainView``;
* images: float32 torch [H, W, 3] in [0, 1]; composited on white for the repair model (paper: white bg).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from go_core.camera import Camera
from go_core.errors import SceneError
from go_core.gaussians import Gaussians


def _mask_from_npz(data, name: str, index: int, shape: tuple[int, int]) -> np.ndarray | None:
    for key in (name, f"train_{index:03d}", f"train_{index:03d}_mask", f"mask_{index}", f"{index}"):
        if key in data.files:
            m = np.asarray(data[key])
            m = m.astype(np.float32) / 255.0 if m.dtype == np.uint8 else m.astype(np.float32)
            return m.reshape(shape)
    if "masks" in data.files:  # a stacked [N, H, W] array in training-view order
        stacked = np.asarray(data["masks"])
        if stacked.ndim == 3 and index < len(stacked) and stacked.shape[1:] == shape:
            m = stacked[index]
            return m.astype(np.float32) / 255.0 if m.dtype == np.uint8 else m.astype(np.float32)
    return None


def training_views(scene_dir: str | Path, mask_dir: str | Path | None = None):
    """(scene, [TrainView]) for the scene artifact's training views, each with a mask."""
    from go_core.scene.artifact import load_scene_artifact
    from go_core.training import TrainView

    scene = load_scene_artifact(scene_dir)
    masks_path = Path(mask_dir) / "masks.npz" if mask_dir is not None else None
    data = np.load(masks_path) if masks_path is not None and masks_path.is_file() else None
    views = []
    try:
        for i, v in enumerate(scene.train):
            h, w = v.image.shape[:2]
            mask = _mask_from_npz(data, v.name, i, (h, w)) if data is not None else None
            if mask is None:
                mask = v.mask
            if mask is None:
                raise SceneError(
                    f"training view {v.name!r} has no mask (neither masks.npz nor the scene)",
                    masks_path or scene_dir,
                )
            views.append(TrainView.from_arrays(v.camera, v.image, mask))
    finally:
        if data is not None:
            data.close()
    return scene, views


def on_white(image: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
    """[H, W, 3] composited over white with its mask."""
    if mask is None:
        return image
    m = mask[..., None]
    return image * m + (1.0 - m)


@torch.no_grad()
def render_rgb_alpha(
    g: Gaussians, cam: Camera, background: float = 1.0, backend: str = "auto", sh_degree: int | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """(rgb [H, W, 3] in [0, 1], alpha [H, W]) of ``g`` seen by ``cam`` over a uniform background."""
    return render_differentiable(g, cam, background, backend, sh_degree)


def render_differentiable(
    g: Gaussians, cam: Camera, background: float = 1.0, backend: str = "auto", sh_degree: int | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    from go_core.render import render_gaussians

    kw = {} if sh_degree is None else {"sh_degree": sh_degree}
    out = render_gaussians(
        g,
        cam.viewmat_tensor()[None],
        cam.K_tensor()[None],
        cam.width,
        cam.height,
        background=torch.full((3,), float(background)),
        backend=backend,
        **kw,
    )
    return out.rgb[0].clamp(0.0, 1.0), out.alpha[0, ..., 0]


def to_uint8(img: torch.Tensor | np.ndarray) -> np.ndarray:
    a = img.detach().cpu().numpy() if isinstance(img, torch.Tensor) else np.asarray(img)
    return (np.clip(a, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def from_uint8(a: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.asarray(a, np.float32) / 255.0)


def hwc_to_bchw(img: torch.Tensor) -> torch.Tensor:
    return img.permute(2, 0, 1)[None].contiguous()


def bchw_to_hwc(img: torch.Tensor) -> torch.Tensor:
    return img[0].permute(1, 2, 0).contiguous()
