"""The visual hull's own surface: the geometry baseline that the Gaussians' mesh is measured against.

A voxel's field value is ``threshold − min over views of the mask value`` at its projection (bilinear), so
the zero level set is the boundary of the region every training mask covers (the hull step's rejection
sampling keeps exactly the points where the field is negative).
"""

from __future__ import annotations

import numpy as np

from go_core.camera import Camera
from go_core.coarse.hull import bilinear, hull_bounds
from go_core.mesh.surface import largest_component, marching_cubes
from go_core.mesh.tsdf import VoxelGrid
from go_core.mesh.types import TriMesh


def hull_field(
    grid: VoxelGrid, cameras: list[Camera], masks: list[np.ndarray], threshold: float
) -> np.ndarray:
    """``threshold − min_v mask_v`` at every voxel centre [X,Y,Z] (negative inside the hull)."""
    pts = grid.centres().numpy()
    lowest = np.ones(len(pts), np.float32)
    for cam, mask in zip(cameras, masks, strict=True):
        uv, z = cam.project(pts)
        ok = (z > 0) & np.isfinite(uv).all(1)
        ok &= (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
        value = np.zeros(len(pts), np.float32)
        value[ok] = bilinear(np.asarray(mask, np.float32), uv[ok])
        lowest = np.minimum(lowest, value)
    return (threshold - lowest).reshape(grid.shape)


def hull_mesh(
    cameras: list[Camera], masks: list[np.ndarray], resolution: int = 128, threshold: float = 0.5
) -> TriMesh:
    """The largest component of the visual hull's surface on a ``resolution`` grid over its bounds."""
    lo, hi = hull_bounds(cameras, masks, min_views=len(cameras), threshold=threshold)
    grid = VoxelGrid.around(lo, hi, resolution)
    field = hull_field(grid, cameras, masks, threshold)
    return largest_component(marching_cubes(field, grid.origin, grid.voxel))
