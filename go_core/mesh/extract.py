"""A coloured triangle mesh from a Gaussian model: render depth + alpha + colour from many views (the
training ellipse and a sphere, go_core.mesh.views), fuse them into a TSDF (go_core.mesh.tsdf) over the
visual hull's box, run marching cubes, keep the largest component, decimate to a face budget and colour the
vertices from the fused colours (go_core.mesh.surface); for ``model.glb`` optionally a decimated copy with a
baked texture atlas (go_core.mesh.texture). Deterministic: no randomness anywhere."""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import numpy as np

from go_core.camera import Camera
from go_core.mesh.hull_mesh import hull_field
from go_core.mesh.settings import MeshSettings
from go_core.mesh.surface import compact, decimate, largest_component, marching_cubes, sample_colours
from go_core.mesh.texture import textured_mesh
from go_core.mesh.tsdf import FusionRule, Tsdf, View, VoxelGrid, fuse_narrow_band
from go_core.mesh.types import TexturedMesh, TriMesh
from go_core.mesh.views import fusion_cameras


def render_maps(
    gaussians,
    cameras: list[Camera],
    backend: str,
    batch: int,
    depth: str = "expected",
    free_level: float | None = 0.05,
):
    """Yield (camera, depth [H,W], alpha [H,W], straight rgb [H,W,3], free depth [H,W]) float32 numpy per
    camera; ``depth`` "expected" (alpha-weighted mean) or "median" (where the opacity reaches 1/2), the free
    depth where it reaches ``free_level`` (both NaN where it never does; None without ``free_level``: one
    render pass less)."""
    import torch

    from go_core.render import render_gaussians
    from go_core.render.api import render_median_depth

    if depth not in ("expected", "median"):
        raise ValueError(f"depth must be 'expected' or 'median', got {depth!r}")
    g = gaussians.to(dtype=torch.float32)
    with torch.no_grad():
        for start in range(0, len(cameras), batch):
            chunk = cameras[start : start + batch]
            viewmats = torch.stack([c.viewmat_tensor(device=g.means.device) for c in chunk])
            Ks = torch.stack([c.K_tensor(device=g.means.device) for c in chunk])
            w, h = chunk[0].width, chunk[0].height
            out = render_gaussians(g, viewmats, Ks, w, h, backend=backend)
            alpha = out.alpha[..., 0].cpu().numpy()
            if depth == "median":
                z = render_median_depth(g, viewmats, Ks, w, h, backend=backend).numpy()
            else:
                z = out.depth[..., 0].cpu().numpy()
            free = None
            if free_level is not None:
                free = render_median_depth(g, viewmats, Ks, w, h, level=free_level, backend=backend).numpy()
            rgb = (out.rgb / out.alpha.clamp_min(1e-6)).clamp(0, 1).cpu().numpy()
            for i, cam in enumerate(chunk):
                yield cam, z[i], alpha[i], rgb[i], None if free is None else free[i]


def fusion_rule(settings: MeshSettings, voxel: float) -> FusionRule:
    """The settings' pixel rules on a grid of ``voxel``."""
    return FusionRule(
        settings.truncation_voxels * voxel,
        settings.alpha_threshold,
        settings.carve_alpha,
        settings.occluded_weight,
    )


def fusion_views(
    gaussians, cameras: list[Camera], settings: MeshSettings, free_depth: bool = True
) -> list[View]:
    """The rendered maps of ``gaussians`` from ``cameras`` that the fusion reads (without the free depth
    when ``free_depth`` is false: the surface test, all a bake reads, does not use it)."""
    free_level = settings.carve_alpha if free_depth else None
    maps = render_maps(gaussians, cameras, settings.backend, settings.batch, settings.depth, free_level)
    return [View(*m) for m in maps]


def seen_counts(
    vertices: np.ndarray, views: list[View], rule: FusionRule, chunk: int = 1 << 17
) -> np.ndarray:
    """int [V]: how many views see each vertex as surface, by the fusion's own test
    (go_core.mesh.tsdf.SurfaceLookup.on_surface: alpha at least ``rule.alpha_threshold`` and a depth within
    ``rule.truncation`` of theirs). A wall inside a porous model, reached only by rays that carve through
    it, is seen by none, or by the one view that looks down a tunnel onto it."""
    import torch

    from go_core.mesh.tsdf import PackedView

    packed = [PackedView(v, rule) for v in views]
    points = torch.as_tensor(np.asarray(vertices, np.float32).reshape(-1, 3))
    counts = torch.zeros(len(points), dtype=torch.int32)
    for start in range(0, len(points), chunk):
        part = points[start : start + chunk]
        for view in packed:
            counts[start : start + chunk] += view.lookup(part, rule).on_surface().to(torch.int32)
    return counts.numpy()


def seen_vertices(
    vertices: np.ndarray, views: list[View], rule: FusionRule, min_views: int = 1
) -> np.ndarray:
    """bool [V]: the vertices that at least ``min_views`` views see as surface (``seen_counts``)."""
    return seen_counts(vertices, views, rule) >= min_views


def drop_unseen(mesh: TriMesh, views: list[View], rule: FusionRule, min_views: int = 1) -> TriMesh:
    """The largest component of the faces of ``mesh`` that have a vertex at least ``min_views`` views see
    as surface (``seen_vertices``); a ``CollapsedModelError`` when none has: the model is see-through from
    every direction, and a mesh of it would be the hull's clip, not the object."""
    from go_core.errors import CollapsedModelError

    keep = seen_vertices(mesh.vertices, views, rule, min_views)[mesh.faces].any(axis=1)
    if not keep.any():
        raise CollapsedModelError(
            f"none of the mesh's {len(mesh.faces)} faces has a vertex that {min_views} or more of the "
            f"{len(views)} fusion views see as surface (the model is see-through from every direction)"
        )
    return largest_component(compact(mesh, keep))


def clip_to_hull(
    field: np.ndarray, grid: VoxelGrid, cameras: list[Camera], masks: list[np.ndarray], threshold: float = 0.5
) -> np.ndarray:
    """The intersection of the solid ``field`` (in truncation units, negative inside) with the visual hull:
    max(field, 2·(threshold − min mask)) clamped to [−1, 1], whose zero level is the hull's boundary
    (go_core.mesh.hull_mesh) wherever the hull is the tighter of the two. The object lies inside the hull by
    construction, so nothing outside it can be surface."""
    hull = np.clip(2.0 * hull_field(grid, cameras, masks, threshold), -1.0, 1.0)
    return np.maximum(field, hull.astype(field.dtype))


@dataclass
class Fused:
    """A model's fused TSDF on ``grid`` (its field clipped to the visual hull when the settings ask), with
    the rendered ``views`` and the pixel ``rule`` it was fused by: what the surface is extracted from."""

    grid: VoxelGrid
    views: list[View]
    rule: FusionRule
    tsdf: Tsdf

    def colours_at(self, points: np.ndarray) -> np.ndarray:
        """The fused colour volume's colours [N,3] at world ``points`` (surface.sample_colours)."""
        t, g = self.tsdf, self.grid
        return sample_colours(points, t.colour_sums, t.colour_counts, g.origin, g.voxel)


def fuse_gaussians(
    gaussians,
    train_cameras: list[Camera],
    box: tuple[np.ndarray, np.ndarray],
    settings: MeshSettings,
    masks: list[np.ndarray] | None = None,
) -> Fused:
    """``gaussians`` rendered from the fusion cameras and fused over ``box`` (lo, hi; e.g. the visual hull's
    bounds), clipped to the visual hull of the training ``masks`` when ``settings.clip_to_hull``."""
    if settings.clip_to_hull and masks is None:
        raise ValueError("clip_to_hull needs the training masks")
    if settings.seen_views > settings.ellipse_views + settings.sphere_views:
        raise ValueError(
            f"mesh.seen_views {settings.seen_views} asks for more views than the "
            f"{settings.ellipse_views + settings.sphere_views} fusion views (mesh.ellipse_views + "
            "mesh.sphere_views): every face would be dropped"
        )
    cameras = fusion_cameras(train_cameras, settings.ellipse_views, settings.sphere_views, settings.max_size)
    grid = VoxelGrid.around(box[0], box[1], settings.resolution)
    views, rule = fusion_views(gaussians, cameras, settings), fusion_rule(settings, grid.voxel)
    tsdf = fuse_narrow_band(grid, views, rule)
    if settings.clip_to_hull:
        tsdf.field = clip_to_hull(tsdf.field, grid, train_cameras, masks)
    return Fused(grid, views, rule, tsdf)


def surface(
    fused: Fused, settings: MeshSettings, field: np.ndarray | None = None
) -> tuple[TriMesh, int, int]:
    """The coloured mesh of ``field`` (default: the fused one) on the fused grid: marching cubes, the
    largest component, the faces fewer than ``settings.seen_views`` views see dropped, decimated, vertex
    colours from the fused colours; with the face counts found and kept before decimation."""
    grid, field = fused.grid, fused.tsdf.field if field is None else field
    raw = largest_component(marching_cubes(field, grid.origin, grid.voxel))
    found = len(raw.faces)
    if settings.seen_views:
        raw = drop_unseen(raw, fused.views, fused.rule, settings.seen_views)
    mesh = decimate(raw, settings.max_faces)
    mesh.colours = fused.colours_at(mesh.vertices)
    return mesh, found, len(raw.faces)


def glb_mesh(
    fused: Fused, mesh: TriMesh, gaussians, train_cameras: list[Camera], settings: MeshSettings
) -> TriMesh | TexturedMesh:
    """What ``model.glb`` holds: ``mesh`` itself (vertex colours) when ``settings.texture_size`` is 0, else
    ``mesh`` decimated to ``settings.texture_faces`` with a texture atlas baked from the fusion cameras'
    renders at the training cameras' resolution (go_core.mesh.texture); texels no render sees take the
    colour volume's colour, as the vertices do."""
    if settings.texture_size <= 0:
        return mesh
    cameras = fusion_cameras(train_cameras, settings.ellipse_views, settings.sphere_views, 0)
    views = fusion_views(gaussians, cameras, settings, free_depth=False)
    small = decimate(mesh, settings.texture_faces)
    return textured_mesh(
        small, views, fused.rule, fused.colours_at, settings.texture_size, settings.texture_sharpness
    )


def export_meshes(
    gaussians,
    train_cameras: list[Camera],
    box: tuple[np.ndarray, np.ndarray],
    settings: MeshSettings,
    masks: list[np.ndarray] | None = None,
) -> tuple[TriMesh, TriMesh | TexturedMesh, dict]:
    """``mesh_from_gaussians``'s mesh and summary, with what ``model.glb`` holds (``glb_mesh``) and its
    counts (``glb``) in the summary."""
    fused, mesh, info = _fused_mesh(gaussians, train_cameras, box, settings, masks)
    t0 = time.perf_counter()
    glb = glb_mesh(fused, mesh, gaussians, train_cameras, settings)
    info["seconds"]["texture"] = round(time.perf_counter() - t0, 3)
    info["glb"] = {"vertices": int(len(glb.vertices)), "faces": int(len(glb.faces))}
    if isinstance(glb, TexturedMesh):
        info["glb"]["texture"] = [int(glb.texture.shape[1]), int(glb.texture.shape[0])]
    return mesh, glb, info


def _summary(fused: Fused, mesh: TriMesh, settings: MeshSettings, faces_found: int, faces_kept: int) -> dict:
    return {
        "settings": asdict(settings),
        "views": len(fused.views),
        "grid": list(fused.grid.shape),
        "voxel": fused.grid.voxel,
        "truncation": settings.truncation_voxels * fused.grid.voxel,
        "faces_unseen_dropped": int(faces_found - faces_kept),
        "faces_before_decimation": int(faces_kept),
        "vertices": int(len(mesh.vertices)),
        "faces": int(len(mesh.faces)),
    }


def _fused_mesh(
    gaussians, train_cameras: list[Camera], box, settings: MeshSettings, masks
) -> tuple[Fused, TriMesh, dict]:
    """``fuse_gaussians``, then ``surface``: the fused field, the mesh and its summary (with ``seconds``)."""
    t0 = time.perf_counter()
    fused = fuse_gaussians(gaussians, train_cameras, box, settings, masks)
    t1 = time.perf_counter()
    mesh, faces_found, faces_kept = surface(fused, settings)
    info = _summary(fused, mesh, settings, faces_found, faces_kept)
    info["seconds"] = {"fuse": round(t1 - t0, 3), "surface": round(time.perf_counter() - t1, 3)}
    return fused, mesh, info


def mesh_from_gaussians(
    gaussians,
    train_cameras: list[Camera],
    box: tuple[np.ndarray, np.ndarray],
    settings: MeshSettings,
    masks: list[np.ndarray] | None = None,
) -> tuple[TriMesh, dict]:
    """The coloured surface of ``gaussians`` inside ``box`` (``fuse_gaussians``, then ``surface``) and a
    summary (counts; ``seconds`` per stage, which differ between runs: keep them out of artifacts)."""
    _, mesh, info = _fused_mesh(gaussians, train_cameras, box, settings, masks)
    return mesh, info
