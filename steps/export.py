"""export: the final Gaussians (repaired when available, else coarse) as an INRIA-layout ``.ply`` and, per
``export.formats``, compressed copies for web viewers (``.spz``, ``.splat``, SuperSplat ``.compressed.ply``;
go_core.formats)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from go_pipeline.steps._common import final_model

from go_core import artifacts as art
from go_core import formats
from go_core.ply import save_ply

if TYPE_CHECKING:
    from go_pipeline.steps.params import ExportParams


def run(ctx, inputs: dict[str, Path], params: ExportParams) -> None:
    g, source = final_model(inputs)
    save_ply(g, art.POINT_CLOUD.path(ctx.out_dir), degree=params.sh_degree)
    sizes = {"ply": art.POINT_CLOUD.path(ctx.out_dir).stat().st_size}
    for fmt in params.formats:
        if fmt != "ply":
            sizes[fmt] = formats.write(g.with_sh_degree(params.sh_degree), fmt, ctx.out_dir).stat().st_size
    ctx.record(source=source, gaussians=len(g), sh_degree_stored=g.sh_degree, bytes=sizes)
