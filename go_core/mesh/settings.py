"""The mesh extraction's settings (torch-free: the runner checks them at plan time)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from go_core.coarse.settings import Backend
from go_core.config import setting


@dataclass
class MeshSettings:
    """How a mesh is extracted (the ``mesh`` step's params, docs/geometry.md)."""

    resolution: int = setting(160, ge=16, le=512, doc="voxels along the longest side of the hull's box")
    truncation_voxels: float = setting(3.0, gt=0, doc="TSDF truncation in voxels (docs/geometry.md)")
    alpha_threshold: float = setting(0.5, gt=0, lt=1, doc="rendered alpha >= this (and a depth) is a surface")
    carve_alpha: float = setting(
        0.05, gt=0, lt=1, doc="a ray is empty space up to where its accumulated opacity reaches this"
    )
    occluded_weight: float = setting(
        0.0, ge=0, doc="weight of the -1 vote of a voxel far behind a surface a view saw (0: unobserved)"
    )
    depth: Literal["median", "expected"] = setting(
        "median", doc="fused depth: where the opacity reaches 1/2, or the alpha-weighted mean"
    )
    clip_to_hull: bool = setting(True, doc="intersect the fused solid with the visual hull of the masks")
    seen_views: int = setting(
        2,
        ge=0,
        doc="keep faces with a vertex that at least this many fusion views see as surface (0: keep every "
        "face; a wall inside a porous model is seen through a tunnel, by one view at most)",
    )
    ellipse_views: int = setting(24, ge=0, doc="fusion views on the ellipse of the training cameras")
    sphere_views: int = setting(40, ge=0, doc="fusion views on a Fibonacci sphere around the object")
    max_size: int = setting(256, ge=16, doc="longest image side of the fusion renders, px")
    max_faces: int = setting(200_000, ge=0, doc="decimation budget (0: keep every marching-cubes face)")
    texture_size: int = setting(
        1024,
        ge=0,
        le=8192,
        doc="model.glb: texels along a side of the square texture atlas baked for it (0: vertex colours on "
        "the undecimated mesh, as model_mesh.ply)",
    )
    texture_faces: int = setting(20_000, ge=100, doc="model.glb with a texture: faces after decimation")
    texture_sharpness: float = setting(
        0.5, ge=0, doc="bake weight of a view: cosine between face normal and view ray to this power"
    )
    batch: int = setting(8, ge=1, doc="cameras rendered per rasterizer call")
    backend: Backend = setting("auto", doc="renderer backend")
