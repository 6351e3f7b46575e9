"""One corpus object's pairs: the coarse model rendered at the novel views beside the true renders.

``make_pairs(scene_dir, gaussians)`` reads the rendered scene folder (NeRF-synthetic: the 4 training views
and the novel views as ``test``) and returns uint8 / float16 arrays, written by the driver as ``pairs.npz``:

* ``novel_coarse_rgb`` [N, H, W, 3] coarse render on white, ``novel_coarse_alpha`` [N, H, W] its coverage,
  ``novel_coarse_depth`` [N, H, W] float16 expected depth (for reprojecting a reference view later);
* ``novel_rgba`` [N, H, W, 4] the true render (straight RGB, alpha = true coverage);
* ``train_rgba`` [4, H, W, 4] the training views, ``train_coarse_rgb`` / ``train_coarse_alpha`` /
  ``train_coarse_depth`` the coarse model at them (how well it fits what it saw; the prior's identity
  pairs, where the render is already right);
* ``novel_c2w`` [N, 4, 4], ``train_c2w`` [4, 4, 4] OpenGL camera-to-world matrices, ``intrinsics`` [4]
  (fx, fy, cx, cy), all float64.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from go_core.compact.reference import c2w_opengl
from go_core.io.images import composite, to_uint8


def coarse_at(gaussians, cams, prefix: str) -> dict[str, np.ndarray]:
    """The coarse model rendered on white at ``cams``: ``{prefix}_coarse_rgb`` uint8 [N, H, W, 3],
    ``_alpha`` uint8 [N, H, W] and ``_depth`` (expected depth) float16 [N, H, W]."""
    import torch

    from go_core.render import render_camera

    rgbs, alphas, depths = [], [], []
    white = torch.ones(3)
    g = gaussians.to(device="cpu")
    with torch.no_grad():
        for cam in cams:
            out = render_camera(g, cam, background=white)
            rgbs.append(to_uint8(out.rgb[0].clamp(0, 1).numpy()))
            alphas.append(to_uint8(out.alpha[0, ..., 0].clamp(0, 1).numpy()))
            depths.append(out.depth[0, ..., 0].numpy().astype(np.float16))
    names = (f"{prefix}_coarse_rgb", f"{prefix}_coarse_alpha", f"{prefix}_coarse_depth")
    return dict(zip(names, (np.stack(rgbs), np.stack(alphas), np.stack(depths)), strict=True))


def _rgba(views) -> np.ndarray:
    return np.stack([np.concatenate([to_uint8(v.image), to_uint8(v.mask)[..., None]], -1) for v in views])


def make_pairs(scene_dir: Path, gaussians) -> dict[str, np.ndarray]:
    """The arrays of ``pairs.npz`` (module docstring) for a rendered scene folder and its coarse model."""
    from go_core.scene.loader import load_scene

    scene = load_scene(scene_dir)
    k = scene.train_cameras[0].K
    return {
        **coarse_at(gaussians, scene.test_cameras, "novel"),
        "novel_rgba": _rgba(scene.test),
        "train_rgba": _rgba(scene.train),
        **coarse_at(gaussians, scene.train_cameras, "train"),
        "novel_c2w": np.stack([c2w_opengl(c) for c in scene.test_cameras]),
        "train_c2w": np.stack([c2w_opengl(c) for c in scene.train_cameras]),
        "intrinsics": np.array([k[0, 0], k[1, 1], k[0, 2], k[1, 2]], np.float64),
    }


def train_views(scene_dir: Path, gaussians) -> dict[str, np.ndarray]:
    """The coarse model rendered at the training views: ``train_coarse_rgb`` / ``_alpha`` / ``_depth`` (to
    add the depth to a ``pairs.npz`` written before it was stored)."""
    from go_core.scene.loader import load_scene

    return coarse_at(gaussians, load_scene(scene_dir).train_cameras, "train")


def on_white(rgba: np.ndarray) -> np.ndarray:
    """uint8 RGBA (straight) [..., 4] -> float64 RGB on white in [0, 1]."""
    return composite(rgba[..., :3].astype(np.float64) / 255.0, rgba[..., 3].astype(np.float64) / 255.0)


def pair_stats(arrays: dict[str, np.ndarray]) -> dict:
    """PSNR of the coarse renders against the truth on white, and the silhouette IoU, per novel view."""
    truth = on_white(arrays["novel_rgba"])
    coarse = arrays["novel_coarse_rgb"].astype(np.float64) / 255.0
    mse = ((truth - coarse) ** 2).reshape(len(truth), -1).mean(1)
    psnr = -10.0 * np.log10(np.maximum(mse, 1e-12))
    a_true = arrays["novel_rgba"][..., 3] > 127
    a_coarse = arrays["novel_coarse_alpha"] > 127
    inter = (a_true & a_coarse).reshape(len(truth), -1).sum(1)
    union = np.maximum((a_true | a_coarse).reshape(len(truth), -1).sum(1), 1)
    return {
        "novel_psnr": [round(float(x), 3) for x in psnr],
        "novel_psnr_mean": round(float(psnr.mean()), 3),
        "novel_silhouette_iou_mean": round(float((inter / union).mean()), 4),
    }
