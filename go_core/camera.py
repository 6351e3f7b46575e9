"""Cameras: ONE convention for the whole project.

Convention (the same as COLMAP, OpenCV and gsplat):
* camera frame: +x right, +y down, +z forward (the camera looks along +z);
* ``world_to_cam`` is the 4x4 world-to-camera matrix ("viewmat" in gsplat), rotation orthonormal;
* ``K`` is the 3x3 pinhole intrinsic matrix in pixels, in continuous image coordinates whose top-left
  image corner is (0, 0): the centre of pixel (col i, row j) is (i + 0.5, j + 0.5);
* a world point X projects to ``u = fx * Xc.x / Xc.z + cx`` (column), ``v = fy * Xc.y / Xc.z + cy`` (row).

NeRF-synthetic / Blender / OpenGL camera-to-world matrices (+y up, looking along -z) are converted on read by
negating the 2nd and 3rd columns of their rotation (``Camera.from_opengl_c2w``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

_FLIP_YZ = np.diag([1.0, -1.0, -1.0, 1.0])


@dataclass(frozen=True)
class Camera:
    """A pinhole camera with its image size; arrays are float64 numpy."""

    name: str
    width: int
    height: int
    K: np.ndarray = field(repr=False)
    world_to_cam: np.ndarray = field(repr=False)

    @staticmethod
    def from_opengl_c2w(name: str, width: int, height: int, K: np.ndarray, c2w_gl: np.ndarray) -> Camera:
        c2w_cv = np.asarray(c2w_gl, dtype=np.float64) @ _FLIP_YZ
        return Camera(name, int(width), int(height), np.asarray(K, np.float64), np.linalg.inv(c2w_cv))

    @staticmethod
    def from_intrinsics(
        name: str,
        width: int,
        height: int,
        fx: float,
        fy: float,
        cx: float,
        cy: float,
        world_to_cam: np.ndarray,
    ) -> Camera:
        K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        return Camera(name, int(width), int(height), K, np.asarray(world_to_cam, np.float64))

    @property
    def cam_to_world(self) -> np.ndarray:
        return np.linalg.inv(self.world_to_cam)

    @property
    def opengl_c2w(self) -> np.ndarray:
        return self.cam_to_world @ _FLIP_YZ

    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates."""
        R, t = self.world_to_cam[:3, :3], self.world_to_cam[:3, 3]
        return -R.T @ t

    @property
    def forward(self) -> np.ndarray:
        """Unit viewing direction (+z of the camera) in world coordinates."""
        return self.world_to_cam[2, :3].copy()

    @property
    def up(self) -> np.ndarray:
        """Unit 'up' direction of the image (-y of the camera) in world coordinates."""
        return -self.world_to_cam[1, :3]

    def scaled(self, factor: float) -> Camera:
        """The same camera for an image resized by ``factor`` (continuous-coordinate convention)."""
        K = self.K.copy()
        K[:2] *= factor
        w, h = round(self.width * factor), round(self.height * factor)
        return Camera(self.name, w, h, K, self.world_to_cam.copy())

    def turned(self, rotvec: np.ndarray) -> Camera:
        """The camera turned about its own centre by the rotation vector ``rotvec`` (radians, camera frame):
        ``world_to_cam' = [exp([rotvec]x) | 0] · world_to_cam``, the same centre looking elsewhere."""
        from scipy.spatial.transform import Rotation

        turn = Rotation.from_rotvec(np.asarray(rotvec, np.float64)).as_matrix()
        w2c = self.world_to_cam.copy()
        w2c[:3, :3] = turn @ w2c[:3, :3]
        w2c[:3, 3] = turn @ w2c[:3, 3]
        return Camera(self.name, self.width, self.height, self.K, w2c)

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project world points [N,3] → (pixel coords [N,2] as (u=col, v=row), depth z [N]).

        Written per column: numpy's [N,3]@[3,3] matmul is ~10x slower for the large N of the visual hull."""
        R, t = self.world_to_cam[:3, :3], self.world_to_cam[:3, 3]
        x, y, z = points[:, 0], points[:, 1], points[:, 2]
        xc = R[0, 0] * x + R[0, 1] * y + R[0, 2] * z + t[0]
        yc = R[1, 0] * x + R[1, 1] * y + R[1, 2] * z + t[1]
        zc = R[2, 0] * x + R[2, 1] * y + R[2, 2] * z + t[2]
        K = self.K
        with np.errstate(divide="ignore", invalid="ignore"):
            a, b = xc / zc, yc / zc
        return np.stack([K[0, 0] * a + K[0, 1] * b + K[0, 2], K[1, 1] * b + K[1, 2]], axis=1), zc

    def viewmat_tensor(self, dtype=None, device=None):
        import torch

        return torch.as_tensor(self.world_to_cam, dtype=dtype or torch.float32, device=device)

    def K_tensor(self, dtype=None, device=None):
        import torch

        return torch.as_tensor(self.K, dtype=dtype or torch.float32, device=device)


def look_at_point(cameras: list[Camera]) -> np.ndarray:
    """Least-squares point closest to all optical axes (the common look-at centre)."""
    A = np.zeros((3, 3))
    b = np.zeros(3)
    for cam in cameras:
        d = cam.forward / np.linalg.norm(cam.forward)
        P = np.eye(3) - np.outer(d, d)
        A += P
        b += P @ cam.center
    return np.linalg.lstsq(A, b, rcond=None)[0]


def look_at(
    name: str,
    position: np.ndarray,
    target: np.ndarray,
    up: np.ndarray,
    K: np.ndarray,
    width: int,
    height: int,
) -> Camera:
    """A camera at ``position`` looking at ``target`` with image-up close to ``up``."""
    fwd = np.asarray(target, np.float64) - np.asarray(position, np.float64)
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, up)
    if np.linalg.norm(right) < 1e-9:  # up parallel to the viewing direction: pick any perpendicular
        right = np.cross(fwd, np.array([1.0, 0.0, 0.0]) if abs(fwd[0]) < 0.9 else np.array([0.0, 1.0, 0.0]))
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    R = np.stack([right, down, fwd])  # rows: camera axes in world coordinates
    w2c = np.eye(4)
    w2c[:3, :3] = R
    w2c[:3, 3] = -R @ np.asarray(position, np.float64)
    return Camera(name, int(width), int(height), np.asarray(K, np.float64), w2c)


@dataclass(frozen=True)
class Ellipse:
    """An ellipse in 3D: ``p(θ) = center + a·cos θ·u + b·sin θ·v``; ``normal`` points to the cameras' 'up'."""

    center: np.ndarray
    u: np.ndarray
    v: np.ndarray
    a: float
    b: float
    normal: np.ndarray
    target: np.ndarray

    def point(self, theta: np.ndarray | float) -> np.ndarray:
        th = np.asarray(theta, np.float64)[..., None]
        return self.center + self.a * np.cos(th) * self.u + self.b * np.sin(th) * self.v

    def angle_of(self, point: np.ndarray) -> np.ndarray:
        """Ellipse parameter θ ∈ [0, 2π) of the point's projection onto the ellipse plane."""
        d = np.atleast_2d(point) - self.center
        return np.mod(np.arctan2((d @ self.v) / self.b, (d @ self.u) / self.a), 2 * np.pi)

    def camera(self, name: str, theta: float, like: Camera) -> Camera:
        """A camera on the ellipse at ``theta``, looking at the target, with the intrinsics of ``like``."""
        return look_at(name, self.point(theta), self.target, self.normal, like.K, like.width, like.height)


def raise_towards(position: np.ndarray, target: np.ndarray, up: np.ndarray, degrees: float) -> np.ndarray:
    """``position`` rotated about ``target`` by ``degrees`` of elevation towards ``up`` (kept below 89°
    above the plane normal to ``up``), at the same distance from ``target``."""
    up = np.asarray(up, np.float64) / np.linalg.norm(up)
    d = np.asarray(position, np.float64) - target
    dist = float(np.linalg.norm(d))
    horizontal = d - (d @ up) * up
    flat = float(np.linalg.norm(horizontal))
    if flat < 1e-9 * dist:
        raise ValueError("the position lies on the up axis through the target: no elevation to raise")
    elevation = min(np.arctan2(d @ up, flat) + np.radians(degrees), np.radians(89.0))
    return target + dist * (np.cos(elevation) * horizontal / flat + np.sin(elevation) * up)


def fit_ellipse(cameras: list[Camera]) -> Ellipse:
    """Fit an ellipse through the camera centres, around their look-at centre.

    The plane is the best-fit plane of the centres (smallest principal direction as normal) through the
    look-at point's projection; the axes are the in-plane principal directions; the semi-axes solve
    ``x²/a² + y²/b² = 1`` in least squares. Use TRAINING cameras only: test cameras must never shape a path.
    """
    if len(cameras) < 2:
        raise ValueError("fitting an ellipse needs at least 2 cameras")
    centers = np.stack([c.center for c in cameras])
    target = look_at_point(cameras) if len(cameras) >= 2 else centers.mean(0)
    mean = centers.mean(0)
    _, _, vt = np.linalg.svd(centers - mean)
    u, v, normal = vt[0], vt[1], vt[2]
    mean_up = np.mean([c.up for c in cameras], axis=0)
    if normal @ mean_up < 0:
        normal = -normal
    v = np.cross(normal, u)  # right-handed (u, v, normal)
    center = target + ((mean - target) @ normal) * normal  # look-at point projected into the plane
    d = centers - center
    x, y = d @ u, d @ v
    A = np.stack([x**2, y**2], axis=1)
    coef, *_ = np.linalg.lstsq(A, np.ones(len(cameras)), rcond=None)
    radius = float(np.sqrt(np.mean(x**2 + y**2)))
    a = float(1.0 / np.sqrt(coef[0])) if coef[0] > 1e-12 else radius
    b = float(1.0 / np.sqrt(coef[1])) if coef[1] > 1e-12 else radius
    return Ellipse(center, u, v, a, b, normal, target)
