"""Camera projection of 3D Gaussians to screen-space 2D Gaussians (vectorised torch, all backends but gsplat).

Autograd differentiates everything here, including w.r.t. the viewmats (camera pose). The maths is
documented in docs/rendering.md; the numerically delicate parts are:

* the 2D covariance is built as ``T Tᵀ`` with ``T = J W R S`` (2x3), so its determinant is the sum of the
  squared 2x2 minors of ``T`` (Cauchy-Binet): never negative, no cancellation, and ``det(Σ + 0.3 I) ≥ 0.09``;
* every quantity that can be undefined for culled Gaussians (depth ≤ 0, huge covariances) is replaced by a
  safe value *before* it enters an operation, so no NaN/inf reaches the values or the gradients.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from go_core.sh import MAX_SH_DEGREE, eval_sh, num_sh_bases

EPS2D = 0.3  # low-pass filter (pixels²) added to every projected covariance
MAX_AXIS_PX = 1e8  # projected extents beyond this are culled (keeps float32 determinants finite)


@dataclass
class Projected:
    """Screen-space Gaussians for C cameras (culled ones have radius 0 and finite placeholder values)."""

    means2d: torch.Tensor  # [C,N,2] pixels
    conics: torch.Tensor  # [C,N,3] upper triangle (a, b, c) of the inverse 2D covariance
    colors: torch.Tensor  # [C,N,3]
    opacities: torch.Tensor  # [C,N] (times the antialiasing compensation when enabled)
    depths: torch.Tensor  # [C,N] camera-space z
    radii: torch.Tensor  # [C,N] int32 3-sigma pixel radius, 0 = culled


def check_colors(colors: torch.Tensor, sh_degree: int | None) -> None:
    """ValueError unless ``colors`` fits ``sh_degree``: SH coefficients [N,≥(d+1)²,3], or RGB [N,3] without
    a degree (shared by the projection backends)."""
    if sh_degree is None:
        if colors.dim() != 2 or colors.shape[-1] != 3:
            raise ValueError(f"without sh_degree colors must be RGB [N,3], got {tuple(colors.shape)}")
        return
    if colors.dim() != 3 or colors.shape[-1] != 3 or colors.shape[1] < num_sh_bases(sh_degree):
        raise ValueError(
            f"sh_degree={sh_degree} needs colors [N,≥{num_sh_bases(sh_degree)},3], got {tuple(colors.shape)}"
        )
    if not 0 <= sh_degree <= MAX_SH_DEGREE:
        raise ValueError(f"SH degree must be in 0..{MAX_SH_DEGREE}, got {sh_degree}")


def quat_to_rotmat(quats: torch.Tensor) -> torch.Tensor:
    """Rotation matrices [N,3,3] from (w,x,y,z) quaternions; normalised here, a zero quaternion gives I."""
    q = torch.nn.functional.normalize(quats, dim=-1)
    w, x, y, z = q.unbind(-1)
    r = torch.stack(
        [
            1 - 2 * (y * y + z * z),
            2 * (x * y - w * z),
            2 * (x * z + w * y),
            2 * (x * y + w * z),
            1 - 2 * (x * x + z * z),
            2 * (y * z - w * x),
            2 * (x * z - w * y),
            2 * (y * z + w * x),
            1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    )
    return r.reshape(quats.shape[:-1] + (3, 3))


def project_gaussians(
    means: torch.Tensor,
    quats: torch.Tensor,
    scales: torch.Tensor,
    opacities: torch.Tensor,
    colors: torch.Tensor,
    viewmats: torch.Tensor,
    Ks: torch.Tensor,
    width: int,
    height: int,
    *,
    sh_degree: int | None = None,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    antialiased: bool = False,
    eps2d: float = EPS2D,
) -> Projected:
    """EWA-project N Gaussians into C cameras (pinhole, OpenCV convention, see go_core.camera)."""
    check_colors(colors, sh_degree)
    C = viewmats.shape[0]
    R = viewmats[:, :3, :3]  # [C,3,3]
    t = viewmats[:, :3, 3]  # [C,3]
    p = torch.einsum("cij,nj->cni", R, means) + t[:, None, :]  # [C,N,3]
    x, y, z = p.unbind(-1)

    finite_p = torch.isfinite(p).all(-1)
    in_depth = (z >= near_plane) & (z <= far_plane) & finite_p
    z_safe = torch.where(in_depth, z, torch.ones_like(z))
    x_safe = torch.where(in_depth, x, torch.zeros_like(x))
    y_safe = torch.where(in_depth, y, torch.zeros_like(y))

    fx, fy = Ks[:, 0, 0, None], Ks[:, 1, 1, None]  # [C,1]
    cx, cy = Ks[:, 0, 2, None], Ks[:, 1, 2, None]
    rz = 1.0 / z_safe
    u = fx * x_safe * rz + cx
    v = fy * y_safe * rz + cy

    J = _perspective_jacobian(x_safe, y_safe, z_safe, rz, Ks, width, height)

    # T = J W R S  (2x3); Σ2d = T Tᵀ + eps2d I
    M = quat_to_rotmat(quats) * scales[:, None, :]  # [N,3,3] = R S
    WM = torch.einsum("cij,njk->cnik", R, M)  # [C,N,3,3]
    T = J @ WM  # [C,N,2,3]
    finite_T = (T.abs() <= MAX_AXIS_PX).all(-1).all(-1)  # also False for NaN
    valid = in_depth & finite_T
    T = torch.where(valid[..., None, None], T, torch.zeros_like(T))
    conics, a, c, b, det, det_raw = _conics(T, eps2d)

    # 3-sigma radius from the largest eigenvalue, computed without cancellation.
    mid = 0.5 * (a + c)
    half_diff = 0.5 * (a - c)
    lam_max = mid + torch.sqrt(torch.clamp_min(half_diff * half_diff + b * b, 0.01))
    radius_f = torch.ceil(3.0 * torch.sqrt(lam_max)).detach()
    on_screen = (
        (u.detach() + radius_f > 0)
        & (u.detach() - radius_f < width)
        & (v.detach() + radius_f > 0)
        & (v.detach() - radius_f < height)
    )
    valid = valid & on_screen
    radii = torch.where(valid, radius_f, torch.zeros_like(radius_f)).to(torch.int32)

    means2d = torch.stack([u, v], dim=-1)

    opac = opacities[None, :].expand(C, -1)
    if antialiased:
        ratio = torch.clamp_min(det_raw / det, 1e-12)  # ∈ (0, 1]
        opac = opac * torch.sqrt(ratio)

    rgb = _view_colors(colors, sh_degree, means, R, t)
    return Projected(means2d, conics, rgb, opac, z_safe, radii)


def _perspective_jacobian(
    x_safe: torch.Tensor,
    y_safe: torch.Tensor,
    z_safe: torch.Tensor,
    rz: torch.Tensor,
    Ks: torch.Tensor,
    width: int,
    height: int,
) -> torch.Tensor:
    """[C,N,2,3] Jacobian of the perspective projection at camera-space points."""
    C = Ks.shape[0]
    fx, fy = Ks[:, 0, 0, None], Ks[:, 1, 1, None]  # [C,1]
    cx, cy = Ks[:, 0, 2, None], Ks[:, 1, 2, None]
    # Jacobian of the perspective projection, evaluated with x/z, y/z clamped to 1.3x the field of view
    # (as 3DGS/gsplat) so Gaussians far outside the image do not get absurd screen-space shapes.
    tan_fovx = 0.5 * width / fx
    tan_fovy = 0.5 * height / fy
    lim_x_pos = (width - cx) / fx + 0.3 * tan_fovx
    lim_x_neg = cx / fx + 0.3 * tan_fovx
    lim_y_pos = (height - cy) / fy + 0.3 * tan_fovy
    lim_y_neg = cy / fy + 0.3 * tan_fovy
    tx = z_safe * torch.minimum(lim_x_pos, torch.maximum(-lim_x_neg, x_safe * rz))
    ty = z_safe * torch.minimum(lim_y_pos, torch.maximum(-lim_y_neg, y_safe * rz))
    zero = torch.zeros_like(z_safe)
    return torch.stack(
        [fx * rz, zero, -fx * tx * rz * rz, zero, fy * rz, -fy * ty * rz * rz], dim=-1
    ).reshape(C, -1, 2, 3)


def _conics(T: torch.Tensor, eps2d: float) -> tuple[torch.Tensor, ...]:
    """(conics [C,N,3], a, c, b, det, det_raw) of Σ2d = T Tᵀ + eps2d I, with det = a c − b² ≥ eps2d²."""
    t0, t1 = T[..., 0, :], T[..., 1, :]
    a_raw = (t0 * t0).sum(-1)
    b = (t0 * t1).sum(-1)
    c_raw = (t1 * t1).sum(-1)
    # Cauchy-Binet: det(T Tᵀ) = Σ of squared 2x2 minors of T
    m01 = t0[..., 0] * t1[..., 1] - t0[..., 1] * t1[..., 0]
    m02 = t0[..., 0] * t1[..., 2] - t0[..., 2] * t1[..., 0]
    m12 = t0[..., 1] * t1[..., 2] - t0[..., 2] * t1[..., 1]
    det_raw = m01 * m01 + m02 * m02 + m12 * m12
    a = a_raw + eps2d
    c = c_raw + eps2d
    det = det_raw + eps2d * (a_raw + c_raw) + eps2d * eps2d  # = a c - b², ≥ eps2d²
    conics = torch.stack([c / det, -b / det, a / det], dim=-1)
    return conics, a, c, b, det, det_raw


def _view_colors(
    colors: torch.Tensor, sh_degree: int | None, means: torch.Tensor, R: torch.Tensor, t: torch.Tensor
) -> torch.Tensor:
    """[C,N,3] colours: SH evaluated towards each camera centre, or the given colours."""
    if sh_degree is not None:
        campos = -torch.einsum("cji,cj->ci", R, t)  # camera centres -Rᵀt [C,3]
        dirs = means[None, :, :] - campos[:, None, :]
        return torch.clamp_min(eval_sh(sh_degree, colors[None], dirs) + 0.5, 0.0)
    return colors[None].expand(R.shape[0], -1, -1)
