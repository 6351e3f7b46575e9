"""mesh: the final model's surface as a coloured triangle mesh, and the visual hull's as the baseline.

Depth, alpha and colour of the final Gaussians (repaired when available, else coarse) are rendered from the
training cameras' ellipse and a sphere of views, fused into a TSDF over the visual hull's box, meshed by
marching cubes (largest component, decimated to ``max_faces``) and coloured per vertex
(go_core.mesh.extract, docs/geometry.md). Outputs ``model_mesh.ply`` (world frame, vertex colours),
``model.glb`` (glTF 2.0 binary: centred on the look-at point, the cameras' up as +Y; the mesh decimated to
``texture_faces`` with a texture baked from the model's renders, or with ``texture_size`` 0 the PLY's mesh
and vertex colours), ``hull_mesh.ply`` (the surface of the
region every training mask covers, for eval's geometry baseline) and ``mesh.json``.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING

from go_pipeline.steps._common import final_model

from go_core import artifacts as art

if TYPE_CHECKING:
    from go_pipeline.steps.params import MeshParams


def run(ctx, inputs: dict[str, Path], params: MeshParams) -> None:
    from dataclasses import asdict, fields

    from go_core.camera import fit_ellipse
    from go_core.coarse.hull import hull_bounds
    from go_core.mesh.extract import export_meshes
    from go_core.mesh.files import write_glb, write_ply
    from go_core.mesh.hull_mesh import hull_mesh
    from go_core.mesh.settings import MeshSettings

    given, _ = art.read_scene_cameras(inputs["scene"])
    cameras = art.read_fitted_cameras(inputs["coarse"], given)  # the frame the model lives in
    masks = art.read_masks(inputs["mask"], len(cameras))
    gaussians, source = final_model(inputs)
    gaussians = gaussians.to(device=ctx.device)
    t0 = time.perf_counter()
    box = hull_bounds(cameras, masks, min_views=len(cameras))
    settings = MeshSettings(**{f.name: getattr(params, f.name) for f in fields(MeshSettings)})
    mesh, glb, info = export_meshes(gaussians, cameras, box, settings, masks)
    seconds = info.pop("seconds")
    write_ply(mesh, art.MESH_PLY.path(ctx.out_dir))
    ellipse = fit_ellipse(cameras)
    write_glb(glb, art.MESH_GLB.path(ctx.out_dir), up=ellipse.normal, centre=ellipse.target)
    t1 = time.perf_counter()
    hull = hull_mesh(cameras, masks, params.hull_resolution)
    write_ply(hull, art.HULL_MESH.path(ctx.out_dir))
    info.update(
        source=source,
        gaussians=len(gaussians),
        hull={"vertices": int(len(hull.vertices)), "faces": int(len(hull.faces))},
        hull_resolution=params.hull_resolution,
        settings=asdict(settings),
    )
    art.write_json(ctx.out_dir, art.MESH_INFO, info)
    ctx.log.info(
        "mesh: %d vertices, %d faces from %d views of the %s model (%.1f s); hull mesh %d faces (%.1f s)",
        info["vertices"],
        info["faces"],
        info["views"],
        source,
        t1 - t0,
        len(hull.faces),
        time.perf_counter() - t1,
    )
    ctx.record(
        source=source,
        vertices=info["vertices"],
        faces=info["faces"],
        mesh_seconds=round(t1 - t0, 3),
        **{f"{k}_seconds": v for k, v in seconds.items()},
        hull_mesh_seconds=round(time.perf_counter() - t1, 3),
    )
