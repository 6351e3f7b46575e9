"""export: the final Gaussians (repaired when available, else coarse) as an INRIA-layout ``.ply``."""

from __future__ import annotations

from pathlib import Path

from go_pipeline.steps._common import final_model_path

from go_core.gaussians import Gaussians
from go_core.ply import PLY_SH_DEGREE, save_ply


def run(ctx, inputs: dict[str, Path], params: dict) -> None:
    path, source = final_model_path(inputs)
    g = Gaussians.load(path)
    save_ply(g, ctx.out_dir / "point_cloud.ply", degree=int(params.get("sh_degree", PLY_SH_DEGREE)))
    ctx.record(source=source, gaussians=len(g), sh_degree_stored=g.sh_degree)
