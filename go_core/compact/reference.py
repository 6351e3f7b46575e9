"""The reference input of the repair prior: the nearest training view, raw or warped into the novel view.

``nearest_view`` picks the training camera whose viewing direction is closest to the novel one.
``reproject`` warps that photo into the novel camera through the coarse model's expected depth there: each
novel pixel the coarse model covers is lifted to 3D, projected into the training camera and given that
photo's colour (bilinear). The reference alpha is 1 where that lands inside the photo's frame and
silhouette, else 0. There is no occlusion test, so a surface the training view does not see takes the
colour of whatever hides it.

Cameras are OpenGL camera-to-world matrices (NeRF convention, the corpus's ``*_c2w``), intrinsics
(fx, fy, cx, cy) in pixels, pixel centres at +0.5. ``ReferenceViews`` does the same for a scene's training
views and go_core cameras (the repair loop and the per-scene tuning of a prior with a reference input).
"""

from __future__ import annotations

import numpy as np

GL_TO_CV = np.diag([1.0, -1.0, -1.0, 1.0])


def c2w_opengl(cam) -> np.ndarray:
    """The camera-to-world matrix in the NeRF (OpenGL) convention of a go_core (OpenCV) camera."""
    return np.linalg.inv(np.asarray(cam.world_to_cam, np.float64)) @ GL_TO_CV


def intrinsics_of(cam) -> np.ndarray:
    """(fx, fy, cx, cy) of a go_core camera."""
    k = np.asarray(cam.K, np.float64)
    return np.array([k[0, 0], k[1, 1], k[0, 2], k[1, 2]])


def nearest_view(
    novel_c2w: np.ndarray, train_c2w: np.ndarray, exclude: np.ndarray | None = None
) -> np.ndarray:
    """For each novel camera [N, 4, 4], the index of the training camera [T, 4, 4] looking most alike;
    ``exclude`` [N] (optional) names, per novel camera, a training view never chosen for it (a training
    view's own photo is the target there), unless it is the only one."""
    score = -novel_c2w[:, :3, 2] @ -train_c2w[:, :3, 2].T
    if exclude is not None and train_c2w.shape[0] > 1:
        score[np.arange(len(score)), np.asarray(exclude)] = -np.inf
    return np.argmax(score, axis=1)


def _bilinear(image: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """image [H, W, C] sampled at continuous pixel coordinates (u right, v down; centres at +0.5)."""
    h, w = image.shape[:2]
    x, y = u - 0.5, v - 0.5
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]

    def at(yy: np.ndarray, xx: np.ndarray) -> np.ndarray:
        return image[np.clip(yy, 0, h - 1), np.clip(xx, 0, w - 1)]

    top = at(y0, x0) * (1 - fx) + at(y0, x0 + 1) * fx
    bottom = at(y0 + 1, x0) * (1 - fx) + at(y0 + 1, x0 + 1) * fx
    return top * (1 - fy) + bottom * fy


def project(
    depth: np.ndarray,
    coverage: np.ndarray,
    intrinsics: np.ndarray,
    novel_c2w: np.ndarray,
    train_c2w: np.ndarray,
    train_intrinsics: np.ndarray,
    train_size: tuple[int, int],
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(ut, vt, zt, ok) [H, W]: where each novel pixel's point at ``depth`` lands in the training camera
    (continuous pixel coordinates, centres at +0.5), its depth there, and ``ok``: covered (``coverage`` >
    0.5), in front of both cameras, and with all 4 bilinear neighbours inside the training image
    (``train_size`` = (height, width))."""
    h, w = depth.shape
    th, tw = train_size
    fx, fy, cx, cy = (float(t) for t in intrinsics)
    tfx, tfy, tcx, tcy = (float(t) for t in train_intrinsics)
    v, u = np.mgrid[:h, :w].astype(np.float64) + 0.5
    z = depth.astype(np.float64)
    cam = np.stack([(u - cx) / fx * z, (v - cy) / fy * z, z, np.ones_like(z)], -1)  # OpenCV camera frame
    world = cam @ (novel_c2w @ GL_TO_CV).T
    other = world @ np.linalg.inv(train_c2w @ GL_TO_CV).T
    zt = other[..., 2]
    ok = (coverage > 0.5) & (z > 0) & (zt > 1e-6)
    ut = tfx * other[..., 0] / np.where(ok, zt, 1.0) + tcx
    vt = tfy * other[..., 1] / np.where(ok, zt, 1.0) + tcy
    ok &= (ut >= 0.5) & (ut <= tw - 0.5) & (vt >= 0.5) & (vt <= th - 0.5)
    return ut, vt, zt, ok


def reproject(
    depth: np.ndarray,
    coverage: np.ndarray,
    intrinsics: np.ndarray,
    novel_c2w: np.ndarray,
    train_c2w: np.ndarray,
    train_rgb: np.ndarray,
    train_alpha: np.ndarray,
    train_intrinsics: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(rgb [H, W, 3] on white, alpha [H, W] in {0, 1}): the training photo (``train_rgb`` on white,
    ``train_alpha`` its silhouette) seen from the novel camera through ``depth`` where ``coverage`` > 0.5.
    ``train_intrinsics``: the training camera's, when they differ from the novel camera's."""
    own = intrinsics if train_intrinsics is None else train_intrinsics
    ut, vt, _, ok = project(depth, coverage, intrinsics, novel_c2w, train_c2w, own, train_rgb.shape[:2])
    rgb = np.where(ok[..., None], _bilinear(train_rgb, ut, vt), 1.0)
    seen = _bilinear(train_alpha[..., None], ut, vt)[..., 0] > 0.5
    return rgb.astype(np.float32), (ok & seen).astype(np.float32)


class ReferenceViews:
    """A scene's training views as reference inputs: ``warp(camera, depth, coverage, exclude)`` is the
    nearest training view by viewing direction (never ``exclude``: a training view's own photo is the
    target there) warped into ``camera`` through ``depth``. Views: objects with ``camera``, ``image``
    [H, W, 3] (straight colour) and ``mask`` [H, W] (tensors or arrays)."""

    def __init__(self, views) -> None:
        self.rgb, self.alpha, self.c2w, self.intrinsics = [], [], [], []
        for v in views:
            image = np.asarray(v.image, np.float32)
            mask = np.ones(image.shape[:2], np.float32) if v.mask is None else np.asarray(v.mask, np.float32)
            self.rgb.append(image * mask[..., None] + (1.0 - mask[..., None]))
            self.alpha.append(mask)
            self.c2w.append(c2w_opengl(v.camera))
            self.intrinsics.append(intrinsics_of(v.camera))
        self.c2w = np.stack(self.c2w)

    def nearest(self, camera, exclude: int | None = None) -> int:
        """The training view looking most like ``camera`` (``exclude`` never chosen)."""
        skip = None if exclude is None else np.array([exclude])
        return int(nearest_view(c2w_opengl(camera)[None], self.c2w, skip)[0])

    def warp(self, camera, depth: np.ndarray, coverage: np.ndarray, exclude: int | None = None):
        """(rgb [H, W, 3] on white, alpha [H, W]) float32: the reference input at ``camera``."""
        j = self.nearest(camera, exclude)
        return reproject(
            np.asarray(depth, np.float64), np.asarray(coverage), intrinsics_of(camera), c2w_opengl(camera),
            self.c2w[j], self.rgb[j], self.alpha[j], self.intrinsics[j],
        )  # fmt: skip
