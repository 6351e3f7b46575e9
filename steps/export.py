"""export: the final Gaussians (repaired when available, else coarse) as an INRIA-layout ``.ply``."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from go_core import artifacts as art
from go_core.ply import save_ply
from go_pipeline.steps._common import final_model

if TYPE_CHECKING:
    from go_pipeline.steps.params import ExportParams


def run(ctx, inputs: dict[str, Path], params: ExportParams) -> None:
    g, source = final_model(inputs)
    save_ply(g, art.POINT_CLOUD.path(ctx.out_dir), degree=params.sh_degree)
    ctx.record(source=source, gaussians=len(g), sh_degree_stored=g.sh_degree)
