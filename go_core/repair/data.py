"""Reading what the repair steps need from upstream artifacts, and rendering helpers.

* training views: the ``scene`` artifact's training views with the ``mask`` step's masks
  (``masks.npz``; falls back to the scene's own masks), as ``go_core.coarse.loop.TrainView``;
* the repair's views: the coarse stage's own inputs at the cameras a coarse model was fitted with;
* images: float32 torch [H, W, 3] in [0, 1]; composited on white for the repair model (paper: white bg).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from go_core.camera import Camera
from go_core.errors import SceneError
from go_core.gaussians import Gaussians
from go_core.io.images import composite, to_uint8  # noqa: F401  (to_uint8 re-exported)

if TYPE_CHECKING:
    from go_core.coarse.loop import TrainView


def training_views(
    scene_dir: str | Path, mask_dir: str | Path | None = None, coarse_dir: str | Path | None = None
):
    """(scene, [TrainView]) for the scene artifact's training views, each with its mask: the ``mask`` step's
    ``masks.npz`` when ``mask_dir`` is given, else the scene's own masks. With ``coarse_dir``, the cameras
    are the ones the coarse model was fitted with (its ``cameras.json``, when it wrote one: refined with
    coarse.refine_poses),
    so a stage that renders the coarse model at the training views sees it where it was fitted."""
    from go_core import artifacts as art
    from go_core.coarse.loop import TrainView

    scene = art.read_scene(scene_dir)
    if mask_dir is not None:
        masks = art.read_masks(mask_dir, len(scene.train))
    else:
        masks = [v.mask for v in scene.train]
    cameras = scene.train_cameras
    if coarse_dir is not None:
        cameras = art.read_fitted_cameras(coarse_dir, cameras)
    views = []
    for v, mask, cam in zip(scene.train, masks, cameras, strict=True):
        if mask is None:
            raise SceneError(f"training view {v.name!r} has no mask (run the mask step)", scene_dir)
        if mask.shape != v.image.shape[:2]:
            raise SceneError(f"mask of {v.name!r} is {mask.shape}, image {v.image.shape[:2]}", mask_dir)
        views.append(TrainView.from_arrays(cam, v.image, mask))
    return scene, views


def repair_views(views: list[TrainView], coarse_dir: str | Path) -> list[TrainView]:
    """The repair's views: ``views`` (the coarse stage's inputs, go_core.coarse.loop.TrainView) at the cameras
    the coarse model in ``coarse_dir`` was fitted with (its ``cameras.json``; refined with
    coarse.refine_poses), without the depth priors, which the repair does not use."""
    from go_core import artifacts as art

    cameras = art.read_fitted_cameras(coarse_dir, [v.camera for v in views])
    return [replace(v, camera=c, depth=None) for v, c in zip(views, cameras, strict=True)]


def on_white(image: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
    """[H, W, 3] composited over white with its mask."""
    return composite(image, mask, 1.0)


@torch.no_grad()
def render_rgb_alpha(
    g: Gaussians, cam: Camera, background: float = 1.0, backend: str = "auto", sh_degree: int | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """(rgb [H, W, 3] in [0, 1], alpha [H, W]) of ``g`` seen by ``cam`` over a uniform background."""
    return render_differentiable(g, cam, background, backend, sh_degree)


def _render_on(g: Gaussians, cam: Camera, background: float, backend: str, sh_degree: int | None):
    """The rasterizer's output (go_core.render.RenderOutput) for ``cam`` on a uniform grey ``background``."""
    from go_core.render import render_camera

    kw = {} if sh_degree is None else {"sh_degree": sh_degree}
    return render_camera(g, cam, background=torch.full((3,), float(background)), backend=backend, **kw)


@torch.no_grad()
def render_rgb_alpha_depth(
    g: Gaussians, cam: Camera, backend: str = "auto", sh_degree: int | None = None
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(rgb [H, W, 3] on white, alpha [H, W], expected depth [H, W]) of ``g`` seen by ``cam``."""
    out = _render_on(g, cam, 1.0, backend, sh_degree)
    return out.rgb[0].clamp(0.0, 1.0), out.alpha[0, ..., 0], out.depth[0, ..., 0]


def render_differentiable(
    g: Gaussians, cam: Camera, background: float = 1.0, backend: str = "auto", sh_degree: int | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """(rgb [H, W, 3] on ``background``, alpha [H, W]) of ``g`` seen by ``cam``, with gradients."""
    out = _render_on(g, cam, background, backend, sh_degree)
    return out.rgb[0].clamp(0.0, 1.0), out.alpha[0, ..., 0]


def from_uint8(a: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.asarray(a, np.float32) / 255.0)


def hwc_to_bchw(img: torch.Tensor) -> torch.Tensor:
    return img.permute(2, 0, 1)[None].contiguous()


def bchw_to_hwc(img: torch.Tensor) -> torch.Tensor:
    return img[0].permute(1, 2, 0).contiguous()


def framed_input(
    frame,
    resolution: int,
    rgb: torch.Tensor,
    alpha: torch.Tensor | None = None,
    reference: tuple[torch.Tensor, torch.Tensor] | None = None,
) -> torch.Tensor:
    """A repair model's input square [1, 3 | 4 | 8, r, r]: ``rgb`` [H, W, 3] on white, then (a repair prior)
    its ``alpha`` [H, W] and a ``reference`` view's RGB and alpha. ``frame`` is a go_core.diffusion.frame
    Frame; RGB outside the image is white, alpha 0 (no object)."""
    parts = [frame.to_square(hwc_to_bchw(rgb), resolution)]
    if alpha is not None:
        parts.append(frame.to_square(alpha[None, None].float(), resolution, background=0.0))
    if reference is not None:
        ref_rgb, ref_alpha = reference
        parts.append(frame.to_square(hwc_to_bchw(ref_rgb), resolution))
        parts.append(frame.to_square(ref_alpha[None, None].float(), resolution, background=0.0))
    return torch.cat(parts, 1)
