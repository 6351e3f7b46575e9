"""depth (optional prior): per-view monocular disparity from a LOCAL transformers DPT / Depth-Anything
checkpoint folder (``model_path``). Without one the runner skips the step (steps/registry.py: a skipped
``depth.json`` with the reason, an empty ``depth.npz``) and the coarse stage runs without the depth loss.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from go_core import artifacts as art
from go_core.coarse.depth_prior import DepthEstimator, save_depth_priors
from go_core.extras import require_extra

if TYPE_CHECKING:
    from go_pipeline.steps.params import DepthParams


def run(ctx, inputs: dict[str, Path], params: DepthParams) -> None:
    # without a model (depth.model_path empty) the runner skips this step without a worker (steps/registry.py)
    require_extra("sd15", "the depth prior (depth.model_path, a transformers model)")
    estimator = DepthEstimator(Path(params.model_path), device="cpu")
    scene = art.read_scene(inputs["scene"])
    maps = []
    bar = ctx.progress(len(scene.train), "depth prior")
    for v in scene.train:
        maps.append(estimator(v.image))
        bar.advance()
    bar.close()
    save_depth_priors(ctx.out_dir, maps)
    info = {"status": "ok", "model": estimator.name, "kind": "disparity", "views": len(maps)}
    art.write_json(ctx.out_dir, art.DEPTH_INFO, info)
    ctx.record(**info)
