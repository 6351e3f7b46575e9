"""Camera pose corrections optimised through the rasterizer's pose gradients (viewmats).

A correction per view is a rotation ``exp([ω]×)`` and a translation ``τ`` applied on the camera side:
``world_to_cam' = [exp([ω]×) | τ] · world_to_cam`` (ω, τ in the camera frame: a turn about the camera's own
centre and a shift along its own axes), both zero at the start. ``PoseCorrection`` holds them for a set of
views; views listed in ``fixed`` keep theirs at zero (the gauge of a joint optimisation with the scene).
``refine_pose`` fits one camera to a photo with the model frozen (CF evaluation); ``JointPoses`` optimises
the training views' corrections together with the Gaussians (``coarse.refine_poses``).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from go_core.camera import Camera


def so3_exp(omega: torch.Tensor) -> torch.Tensor:
    """Rodrigues: axis-angle [..., 3] → rotation [..., 3, 3]; differentiable, exact to second order at 0."""
    theta2 = (omega * omega).sum(-1, keepdim=True)[..., None]  # [...,1,1]
    theta = torch.sqrt(theta2 + 1e-24)
    small = theta2 < 1e-12
    a = torch.where(small, 1.0 - theta2 / 6.0, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24.0, (1.0 - torch.cos(theta)) / theta2.clamp_min(1e-24))
    x, y, z = omega.unbind(-1)
    zero = torch.zeros_like(x)
    k = torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], -1).unflatten(-1, (3, 3))
    eye = torch.eye(3, dtype=omega.dtype, device=omega.device).expand_as(k)
    return eye + a * k + b * (k @ k)


class PoseCorrection(torch.nn.Module):
    """Rotation + translation corrections of ``num_views`` cameras; ``fixed`` views stay as given."""

    def __init__(self, num_views: int, fixed: tuple[int, ...] = (), dtype=torch.float32) -> None:
        super().__init__()
        self.rotation = torch.nn.Parameter(torch.zeros(num_views, 3, dtype=dtype))
        self.translation = torch.nn.Parameter(torch.zeros(num_views, 3, dtype=dtype))
        free = torch.ones(num_views, 1, dtype=dtype)
        free[list(fixed)] = 0.0
        self.register_buffer("free", free)

    def matrices(self, index: torch.Tensor | slice = slice(None)) -> torch.Tensor:
        """[V,4,4] corrections (identity for fixed views)."""
        free = self.free[index]
        R = so3_exp(self.rotation[index] * free)
        D = torch.eye(4, dtype=R.dtype).repeat(R.shape[0], 1, 1)
        D[:, :3, :3] = R
        D[:, :3, 3] = self.translation[index] * free
        return D

    def forward(self, viewmats: torch.Tensor, index: torch.Tensor | slice = slice(None)) -> torch.Tensor:
        return self.matrices(index).to(viewmats.dtype) @ viewmats

    @torch.no_grad()
    def apply_to(self, cameras: list[Camera]) -> list[Camera]:
        """The corrected cameras (float64 maths)."""
        D = self.matrices().double().numpy()
        return [Camera(c.name, c.width, c.height, c.K, D[i] @ c.world_to_cam) for i, c in enumerate(cameras)]


def mean_camera_distance(cameras: list[Camera]) -> float:
    """The cameras' mean distance from the world origin (1 if all sit on it): the scale of pose steps and
    of centre priors, so they behave the same at any scene scale."""
    return float(np.mean([np.linalg.norm(c.center) for c in cameras])) or 1.0


def rotation_angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Angle between the rotations of two world-to-camera matrices."""
    r = a[:3, :3] @ b[:3, :3].T
    return float(np.degrees(np.arccos(np.clip((np.trace(r) - 1.0) / 2.0, -1.0, 1.0))))


def refine_pose(
    gaussians,
    camera: Camera,
    target: torch.Tensor,
    *,
    iterations: int = 200,
    lr_rotation: float = 2e-3,
    lr_translation: float = 2e-3,
    sh_degree: int | None = None,
    background: torch.Tensor | None = None,
    backend: str = "auto",
) -> tuple[Camera, list[float]]:
    """Fit ``camera``'s pose to ``target`` [H,W,3] (on ``background``) with the Gaussians frozen: Adam on the
    mean absolute error, learning rates decayed ×0.1 (cosine) over the run. Returns the refined camera and
    the loss per iteration. ``lr_translation`` is in world units per step, scaled by the camera's distance
    to the world origin so it behaves the same at any scene scale."""
    from go_core.render import render_gaussians

    g = gaussians.detach() if hasattr(gaussians, "detach") else gaussians
    corr = PoseCorrection(1)
    scale = float(np.linalg.norm(camera.center)) or 1.0
    opt = torch.optim.Adam(
        [
            {"params": [corr.rotation], "lr": lr_rotation},
            {"params": [corr.translation], "lr": lr_translation * scale},
        ]
    )
    base = [lr_rotation, lr_translation * scale]
    viewmat = camera.viewmat_tensor()[None]
    K = camera.K_tensor()[None]
    bg = background if background is not None else torch.ones(3)
    losses = []
    for it in range(iterations):
        decay = 0.1 + 0.9 * 0.5 * (1.0 + np.cos(np.pi * it / max(iterations, 1)))
        for group, lr in zip(opt.param_groups, base, strict=True):
            group["lr"] = lr * decay
        out = render_gaussians(
            g,
            corr(viewmat),
            K,
            camera.width,
            camera.height,
            sh_degree=g.sh_degree if sh_degree is None else sh_degree,
            background=bg,
            backend=backend,
        )
        loss = (out.rgb[0] - target).abs().mean()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
    return corr.apply_to([camera])[0], losses


class JointPoses:
    """Pose corrections of the training views, optimised with the Gaussians (``coarse.refine_poses``).

    View 0 is the gauge (its correction stays zero). Its own Adam: rotations at ``lr_rotation`` (radians),
    translations at ``lr_translation`` × the cameras' mean distance from the world origin (so it behaves the
    same at any scene scale), both cosine-decayed to ×0.1 from ``start`` to ``end``. Before ``start`` the
    poses are used as given and no pose gradient is computed."""

    def __init__(
        self, cameras: list[Camera], lr_rotation: float, lr_translation: float, start: int, end: int
    ) -> None:
        self.cameras = list(cameras)
        self.correction = PoseCorrection(len(cameras), fixed=(0,))
        scale = mean_camera_distance(cameras)
        self.base_lrs = (float(lr_rotation), float(lr_translation) * scale)
        self.optimizer = torch.optim.Adam(
            [
                {"params": [self.correction.rotation], "lr": self.base_lrs[0]},
                {"params": [self.correction.translation], "lr": self.base_lrs[1]},
            ]
        )
        self.start, self.end = int(start), int(end)
        self.viewmats = torch.stack([c.viewmat_tensor() for c in cameras])  # [V,4,4] float32

    def active(self, step: int) -> bool:
        return step >= self.start

    def viewmat(self, index: int, step: int) -> torch.Tensor:
        """[1,4,4] corrected world-to-camera of view ``index`` (differentiable when active)."""
        sel = slice(index, index + 1)
        if self.active(step):
            return self.correction(self.viewmats[sel], sel)
        with torch.no_grad():
            return self.correction(self.viewmats[sel], sel)

    def step(self, step: int) -> None:
        """Apply this iteration's pose gradient (after ``loss.backward()``)."""
        if not self.active(step):
            return
        t = min(max((step - self.start) / max(self.end - self.start, 1), 0.0), 1.0)
        decay = 0.1 + 0.9 * 0.5 * (1.0 + math.cos(math.pi * t))  # a Python float: checkpoints hold no numpy
        for group, lr in zip(self.optimizer.param_groups, self.base_lrs, strict=True):
            group["lr"] = lr * decay
        self.optimizer.step()
        self.optimizer.zero_grad(set_to_none=True)

    def corrections(self) -> list[list[float]]:
        """Per view [ωx, ωy, ωz, τx, τy, τz] (camera frame; JSON-able)."""
        with torch.no_grad():
            c = self.correction
            both = torch.cat([c.rotation, c.translation], 1) * c.free
        return [[float(x) for x in row] for row in both.double()]

    def refined_cameras(self) -> list[Camera]:
        return self.correction.apply_to(self.cameras)

    def state_dict(self) -> dict:
        return {"correction": self.correction.state_dict(), "optimizer": self.optimizer.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        self.correction.load_state_dict(state["correction"])
        self.optimizer.load_state_dict(state["optimizer"])


def apply_corrections(cameras: list[Camera], corrections: list[list[float]]) -> list[Camera]:
    """``cameras`` with the per-view corrections of ``JointPoses.corrections`` applied (float64)."""
    corr = PoseCorrection(len(cameras), dtype=torch.float64)
    values = torch.tensor(corrections, dtype=torch.float64).reshape(len(cameras), 6)
    with torch.no_grad():
        corr.rotation.copy_(values[:, :3])
        corr.translation.copy_(values[:, 3:])
    return corr.apply_to(cameras)
