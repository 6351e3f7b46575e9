"""Surface terms of the coarse stage (issue #35, item 4): flat Gaussians whose normals agree with the depth.

* **Flattening** (PGSR, NeuSG): ``mean_i min_k s_ik / extent``; a Gaussian whose smallest axis is near zero
  is a disc, with a well-defined normal (that axis).
* **Depth–normal consistency** (2DGS, Huang et al. SIGGRAPH 2024): the alpha-weighted normal rendered from the
  Gaussians' own normals, ``N``, should equal the normal of the surface the rendered expected depth
  describes, ``n_d`` (central differences of the back-projected depth map):
  ``mean over the eroded mask interior of 1 − N · n_d``. Both normals are in the camera frame and face the
  camera. The gradient reaches the positions through the depth and the rotations, scales and opacities
  through ``N``: the Gaussians form a coherent sheet instead of a volume of blobs that four photos do not
  tell apart.

Both are prior-free (nothing but the Gaussians and the training cameras); each is a coarse param, 0 = off.
"""

from __future__ import annotations

import torch

from go_core.render.projection import quat_to_rotmat


def flatten_loss(log_scales: torch.Tensor, extent: float) -> torch.Tensor:
    """``mean_i min_k exp(log s_ik) / extent``: the Gaussians' smallest axis, in units of the scene extent."""
    return torch.exp(log_scales.min(dim=1).values).mean() / max(float(extent), 1e-12)


def camera_normals(quats: torch.Tensor, log_scales: torch.Tensor, means: torch.Tensor, viewmat: torch.Tensor):
    """Per-Gaussian unit normals [N,3] in the camera frame of ``viewmat`` [4,4] (world → camera): the axis of
    the smallest scale, flipped to face the camera (n · mean_cam < 0)."""
    rot = quat_to_rotmat(quats)  # columns are the local axes in world coordinates
    axis = log_scales.detach().argmin(dim=1)
    n_world = torch.gather(rot, 2, axis.view(-1, 1, 1).expand(-1, 3, 1)).squeeze(2)
    r, t = viewmat[:3, :3], viewmat[:3, 3]
    n_cam = n_world @ r.T
    mean_cam = means.detach() @ r.T + t
    flip = torch.where((n_cam * mean_cam).sum(1, keepdim=True) > 0, -1.0, 1.0)
    return n_cam * flip


def depth_normals(depth: torch.Tensor, K: torch.Tensor) -> torch.Tensor:
    """Unit normals [H,W,3] (camera frame, facing the camera) of the surface a depth map [H,W] describes:
    the cross product of the central differences of the back-projected points (pixel centres at +0.5); the
    one-pixel border is zero."""
    h, w = depth.shape
    v, u = torch.meshgrid(
        torch.arange(h, dtype=depth.dtype) + 0.5, torch.arange(w, dtype=depth.dtype) + 0.5, indexing="ij"
    )
    x = (u - K[0, 2]) / K[0, 0]
    y = (v - K[1, 2]) / K[1, 1]
    pts = torch.stack([x * depth, y * depth, depth], dim=-1)
    du = pts[1:-1, 2:] - pts[1:-1, :-2]
    dv = pts[2:, 1:-1] - pts[:-2, 1:-1]
    n = -torch.linalg.cross(du, dv, dim=-1)
    n = torch.nn.functional.normalize(n, dim=-1, eps=1e-12)
    return torch.nn.functional.pad(n.permute(2, 0, 1), (1, 1, 1, 1)).permute(1, 2, 0)


def valid_pixels(alpha: torch.Tensor, interior: torch.Tensor, threshold: float = 0.5) -> torch.Tensor:
    """Boolean [H,W]: inside the (eroded) mask, opaque here and at the four neighbours the central
    differences use (depth across a silhouette edge has no surface normal)."""
    a = alpha.detach() > threshold
    ok = a & (interior > 0.5)
    inner = torch.zeros_like(ok)
    inner[1:-1, 1:-1] = ok[1:-1, 1:-1] & a[:-2, 1:-1] & a[2:, 1:-1] & a[1:-1, :-2] & a[1:-1, 2:]
    return inner


def depth_normal_loss(
    rendered_normals: torch.Tensor, depth: torch.Tensor, K: torch.Tensor, valid: torch.Tensor
) -> torch.Tensor:
    """``mean over valid pixels of 1 − N · n_d`` with ``N`` the rendered (alpha-weighted, not normalised)
    normal [H,W,3] and ``n_d`` the depth map's unit normal; 0 without valid pixels."""
    if not bool(valid.any()):
        return rendered_normals.sum() * 0.0
    n_d = depth_normals(depth, K)
    dot = (rendered_normals * n_d).sum(-1)
    return (1.0 - dot)[valid].mean()
