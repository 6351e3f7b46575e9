"""depth (optional prior): per-view monocular disparity from a LOCAL transformers DPT / Depth-Anything
checkpoint folder (``model_path``). Without one the step is skipped (recorded: status "skipped" and why),
writes an empty ``depth.npz`` and the coarse stage runs without the depth loss.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from go_core import artifacts as art
from go_core.coarse.depth_prior import DepthEstimator, save_depth_priors

if TYPE_CHECKING:
    from go_pipeline.steps.params import DepthParams

# without a model the runner skips this step without a worker (go_pipeline/skipping.py): a skipped depth.json
# and an empty depth.npz, as the branch below writes when the step is called directly
SKIP_IF_EMPTY = {"model_path": "no depth model configured (depth.model_path is empty): the depth loss is off"}


def run(ctx, inputs: dict[str, Path], params: DepthParams) -> None:
    model_path = params.model_path
    if not model_path:
        reason = SKIP_IF_EMPTY["model_path"]
        save_depth_priors(ctx.out_dir, [])
        art.write_json(ctx.out_dir, art.DEPTH_INFO, {"status": "skipped", "reason": reason, "views": 0})
        ctx.record(status="skipped", reason=reason)
        return
    estimator = DepthEstimator(Path(model_path), device="cpu")
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
