"""A coloured triangle mesh from a Gaussian model: render depth + alpha + colour from many views (the
training ellipse and a sphere, go_core.mesh.views), fuse them into a TSDF (go_core.mesh.tsdf) over the
visual hull's box, run marching cubes, keep the largest component, decimate to a face budget and colour the
vertices from the fused colours (go_core.mesh.surface). Deterministic: no randomness anywhere."""

from __future__ import annotations

import time
from dataclasses import asdict

import numpy as np

from go_core.camera import Camera
from go_core.mesh.settings import MeshSettings
from go_core.mesh.surface import TriMesh, decimate, largest_component, marching_cubes, sample_colours
from go_core.mesh.tsdf import Tsdf, View, VoxelGrid, fuse_narrow_band
from go_core.mesh.views import fusion_cameras


def render_maps(gaussians, cameras: list[Camera], backend: str, batch: int):
    """Yield (camera, depth [H,W], alpha [H,W], straight rgb [H,W,3]) float32 numpy per camera."""
    import torch

    from go_core.render import render_gaussians

    g = gaussians.to(dtype=torch.float32)
    with torch.no_grad():
        for start in range(0, len(cameras), batch):
            chunk = cameras[start : start + batch]
            viewmats = torch.stack([c.viewmat_tensor(device=g.means.device) for c in chunk])
            Ks = torch.stack([c.K_tensor(device=g.means.device) for c in chunk])
            out = render_gaussians(g, viewmats, Ks, chunk[0].width, chunk[0].height, backend=backend)
            alpha = out.alpha[..., 0].cpu().numpy()
            depth = out.depth[..., 0].cpu().numpy()
            rgb = (out.rgb / out.alpha.clamp_min(1e-6)).clamp(0, 1).cpu().numpy()
            for i, cam in enumerate(chunk):
                yield cam, depth[i], alpha[i], rgb[i]


def fuse(gaussians, cameras: list[Camera], grid: VoxelGrid, settings: MeshSettings) -> Tsdf:
    """The TSDF of ``gaussians`` seen from ``cameras``."""
    views = [View(*maps) for maps in render_maps(gaussians, cameras, settings.backend, settings.batch)]
    return fuse_narrow_band(grid, views, settings.truncation_voxels * grid.voxel, settings.alpha_threshold)


def mesh_from_gaussians(
    gaussians, train_cameras: list[Camera], box: tuple[np.ndarray, np.ndarray], settings: MeshSettings
) -> tuple[TriMesh, dict]:
    """The coloured surface of ``gaussians`` inside ``box`` (lo, hi; e.g. the visual hull's bounds), and
    a summary (counts; ``seconds`` per stage, which differ between runs: keep them out of artifacts)."""
    t0 = time.perf_counter()
    cameras = fusion_cameras(train_cameras, settings.ellipse_views, settings.sphere_views, settings.max_size)
    grid = VoxelGrid.around(box[0], box[1], settings.resolution)
    tsdf = fuse(gaussians, cameras, grid, settings)
    t1 = time.perf_counter()
    raw = largest_component(marching_cubes(tsdf.field, grid.origin, grid.voxel))
    mesh = decimate(raw, settings.max_faces)
    mesh.colours = sample_colours(
        mesh.vertices, tsdf.colour_sums, tsdf.colour_counts, grid.origin, grid.voxel
    )
    t2 = time.perf_counter()
    info = {
        "settings": asdict(settings),
        "views": len(cameras),
        "grid": list(grid.shape),
        "voxel": grid.voxel,
        "truncation": settings.truncation_voxels * grid.voxel,
        "faces_before_decimation": int(len(raw.faces)),
        "vertices": int(len(mesh.vertices)),
        "faces": int(len(mesh.faces)),
        "seconds": {"fuse": round(t1 - t0, 3), "surface": round(t2 - t1, 3)},  # not for artifacts
    }
    return mesh, info
