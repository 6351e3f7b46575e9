"""Where the test error is (issue 34, item 4): each test pixel lies outside the true silhouette, or on the
true surface at a point that at least one training view sees, or at one that no training view sees.

The surface comes from the scene's ground-truth mesh: per camera, a z-buffer at the pixel centres
(``rasterize``: the nearest face at each pixel and its exact depth). A test pixel's surface point
is *seen* when some training camera, at ``SUPERSAMPLE`` times its resolution, sees at the point's pixel a
face whose plane passes within ``tolerance`` of the point. (A plane, not a depth, test: at a slanted
surface one pixel spans a large depth range, and a depth test either misses seen points or, with a
neighbourhood, takes in hidden ones. Against a sphere's exact visibility the share seen is within 0.01 per
training camera: tests/test_error_split.py.)
The split of the squared error over the three regions adds up to the whole image's (``summarise``), so a
change in test PSNR can be attributed."""

from __future__ import annotations

import numpy as np

from go_core.mesh.types import TriMesh

REGIONS = ("outside", "seen", "unseen")
SEEN_TOLERANCE = 0.01  # of the mesh's bounding radius: a point this close to a seen face's plane is seen
SUPERSAMPLE = 2  # the training views' face maps at this many times their resolution


def rasterize(mesh: TriMesh, camera) -> tuple[np.ndarray, np.ndarray]:
    """Z-buffer of ``mesh`` at the pixel centres of ``camera``: int64 [H,W] the index of the nearest face
    (-1 where none) and float64 [H,W] its camera-frame depth (inf where none). A pixel belongs to every
    face whose triangle (edges included) holds its centre; the depth is exact for the face's plane
    (1/z is affine in the image). Faces with a vertex behind the camera are left out."""
    uv, z = camera.project(mesh.vertices)
    h, w = camera.height, camera.width
    faces = np.nonzero((z[mesh.faces] > 1e-9).all(1))[0]
    tri = uv[mesh.faces[faces]] - 0.5  # pixel (i, j)'s centre at (i, j)
    lo = np.maximum(np.ceil(tri.min(1)), 0).astype(np.int64)
    hi = np.minimum(np.floor(tri.max(1)), [w - 1, h - 1]).astype(np.int64)
    span = (hi - lo + 1).max(1)
    keep = span > 0
    faces, tri, lo, span = faces[keep], tri[keep], lo[keep], span[keep]
    zs = z[mesh.faces[faces]]  # [F, 3] the kept faces' vertex depths
    pix, face, depth = [], [], []
    size = 1 << int(np.ceil(np.log2(max(int(span.max(initial=1)), 1))))
    for s in (1 << k for k in range(int(np.log2(size)) + 1)):
        chosen = np.nonzero((span <= s) & (span > s // 2))[0]
        for chunk in np.array_split(chosen, max(1, len(chosen) * s * s // 4_000_000 + 1)):
            found = _cover(chunk, s, tri, lo, zs, (h, w))
            pix.append(found[0]), face.append(faces[found[1]]), depth.append(found[2])
    return _nearest(np.concatenate(pix), np.concatenate(face), np.concatenate(depth), (h, w))


def _cover(chunk, s: int, tri, lo, zs, shape) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The (flat pixel, face row, depth) of every pixel centre in an ``s`` x ``s`` box from ``lo`` that the
    triangles ``tri[chunk]`` (image coordinates, pixel centres at integers) hold."""
    h, w = shape
    off = np.stack(np.meshgrid(np.arange(s), np.arange(s), indexing="xy"), -1).reshape(-1, 2)
    px = lo[chunk][:, None, :] + off[None]  # [F, s*s, 2] as (x, y)
    a, b, c = (tri[chunk][:, k][:, None, :] for k in range(3))

    def edge(p, q, r):  # twice the signed area of (p, q, r)
        return (q[..., 0] - p[..., 0]) * (r[..., 1] - p[..., 1]) - (q[..., 1] - p[..., 1]) * (
            r[..., 0] - p[..., 0]
        )

    area = edge(a, b, c)
    w0, w1, w2 = edge(b, c, px), edge(c, a, px), edge(a, b, px)
    eps = 1e-12 * np.abs(area)
    inside = (px[..., 0] < w) & (px[..., 1] < h) & (np.abs(area) > 0)
    inside &= ((w0 >= -eps) & (w1 >= -eps) & (w2 >= -eps)) | ((w0 <= eps) & (w1 <= eps) & (w2 <= eps))
    rows, cols = np.nonzero(inside)
    bary = np.stack([w0[rows, cols], w1[rows, cols], w2[rows, cols]], -1) / area[rows, 0][:, None]
    inv_z = (bary / zs[chunk][rows]).sum(1)
    flat = px[rows, cols, 1] * w + px[rows, cols, 0]
    return flat, chunk[rows], 1.0 / inv_z


def _nearest(pix, face, depth, shape) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel the face with the smallest depth (ties: the lower face index)."""
    faces = np.full(shape[0] * shape[1], -1, np.int64)
    depths = np.full(shape[0] * shape[1], np.inf)
    if len(pix):
        order = np.lexsort((face, depth, pix))
        first = np.ones(len(order), bool)
        first[1:] = pix[order][1:] != pix[order][:-1]
        take = order[first]
        faces[pix[take]], depths[pix[take]] = face[take], depth[take]
    return faces.reshape(shape), depths.reshape(shape)


def face_map(mesh: TriMesh, camera) -> np.ndarray:
    """int64 [H,W]: the index of the face of ``mesh`` seen at each pixel centre, -1 where none."""
    return rasterize(mesh, camera)[0]


def _rays(camera, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """Camera-frame directions [N,3] through pixel centres (xs, ys), with z = 1."""
    pix = np.stack([xs + 0.5, ys + 0.5, np.ones(len(xs))], axis=1)
    return pix @ np.linalg.inv(camera.K).T


def depth_map(mesh: TriMesh, camera) -> np.ndarray:
    """float64 [H,W]: the camera-frame depth of ``mesh`` at each pixel centre, inf where no face."""
    return rasterize(mesh, camera)[1]


def surface_points(camera, depth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The world points [N,3] at the finite pixels of ``depth``, and those pixels as a bool [H,W] map."""
    covered = np.isfinite(depth)
    ys, xs = np.nonzero(covered)
    cam_points = _rays(camera, xs.astype(np.float64), ys.astype(np.float64)) * depth[ys, xs][:, None]
    R, t = camera.world_to_cam[:3, :3], camera.world_to_cam[:3, 3]
    return (cam_points - t) @ R, covered


def seen_by(points: np.ndarray, mesh: TriMesh, camera, faces: np.ndarray, tolerance: float) -> np.ndarray:
    """bool [N]: which ``points`` ``camera`` sees, given its ``face_map`` ``faces``: in front of it, in frame,
    and within ``tolerance`` of the plane of the face it sees at their pixel."""
    uv, z = camera.project(points)
    h, w = faces.shape
    col, row = np.floor(uv[:, 0]).astype(np.int64), np.floor(uv[:, 1]).astype(np.int64)
    inside = (z > 0) & (row >= 0) & (row < h) & (col >= 0) & (col < w)
    face = np.full(len(points), -1, np.int64)
    face[inside] = faces[row[inside], col[inside]]
    hit = face >= 0
    tri = mesh.vertices[mesh.faces[face[hit]]]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
    seen = np.zeros(len(points), bool)
    seen[hit] = np.abs(np.einsum("ij,ij->i", normal, points[hit] - tri[:, 0])) <= tolerance
    return seen


class SeenSurface:
    """The seen/unseen map of test cameras for one ground-truth mesh and its training cameras (their face
    maps made once, at ``SUPERSAMPLE`` times their resolution)."""

    def __init__(self, mesh: TriMesh, train_cameras: list, tolerance: float | None = None):
        from go_core.metrics.geometry import bounding_radius

        self.mesh = mesh
        self.tolerance = SEEN_TOLERANCE * bounding_radius(mesh) if tolerance is None else float(tolerance)
        scaled = [cam.scaled(SUPERSAMPLE) for cam in train_cameras]
        self.train = [(cam, face_map(mesh, cam)) for cam in scaled]

    def regions(self, camera, alpha: np.ndarray) -> dict[str, np.ndarray]:
        """bool [H,W] maps of REGIONS for a test ``camera`` and its true ``alpha`` (> 0.5 is inside);
        an inside pixel where the mesh has no surface counts as unseen."""
        points, covered = surface_points(camera, depth_map(self.mesh, camera))
        seen = np.zeros(len(points), bool)
        for cam, faces in self.train:
            seen |= seen_by(points, self.mesh, cam, faces, self.tolerance)
        seen_map = np.zeros(covered.shape, bool)
        seen_map[covered] = seen
        inside = np.asarray(alpha) > 0.5
        return {"outside": ~inside, "seen": inside & seen_map, "unseen": inside & ~seen_map}


def split_errors(pred: np.ndarray, gt: np.ndarray, regions: dict[str, np.ndarray]) -> dict[str, dict]:
    """Per region of ``regions`` (bool [H,W] maps, e.g. ``SeenSurface.regions``'): its pixels and the sum
    over them of the squared error (mean over the channels) of ``pred`` against ``gt`` ([H,W,3] in [0, 1])."""
    sq = ((np.asarray(pred, np.float64) - np.asarray(gt, np.float64)) ** 2).mean(-1)
    return {r: {"pixels": int(where.sum()), "sse": float(sq[where].sum())} for r, where in regions.items()}


def summarise(per_view: list[dict[str, dict]]) -> dict[str, dict]:
    """Over all views, per region: its share of the pixels, its share of the squared error (the shares add
    up to 1), its own MSE and PSNR, and the PSNR the whole image would have were the other regions exact
    (``psnr_if_rest_exact``: how much that region alone costs)."""
    pixels = {r: sum(v[r]["pixels"] for v in per_view) for r in REGIONS}
    sse = {r: sum(v[r]["sse"] for v in per_view) for r in REGIONS}
    total_px, total_sse = sum(pixels.values()), sum(sse.values())

    def psnr(mse: float) -> float | None:
        return None if mse <= 0 else float(-10.0 * np.log10(mse))

    out = {}
    for r in REGIONS:
        mse = sse[r] / pixels[r] if pixels[r] else 0.0
        out[r] = {
            "pixel_share": pixels[r] / total_px if total_px else 0.0,
            "error_share": sse[r] / total_sse if total_sse else 0.0,
            "mse": mse,
            "psnr": psnr(mse) if pixels[r] else None,
            "psnr_if_rest_exact": psnr(sse[r] / total_px) if total_px else None,
        }
    return out


__all__ = [
    "REGIONS",
    "SEEN_TOLERANCE",
    "SUPERSAMPLE",
    "SeenSurface",
    "depth_map",
    "face_map",
    "rasterize",
    "seen_by",
    "split_errors",
    "summarise",
    "surface_points",
]
