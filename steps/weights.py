"""weights: find the repair model's weights (SD1.5, ControlNet-tile, optional CLIP) before any repair work.

Runs first in the repair chain and costs nothing, so a scene without weights never pays for the leave-one-out
runs, noise pairs or tuning: those steps see ``weights.json`` ``{"status": "missing"}`` and skip with its
reason, and the result is the coarse model (the report says so). Paths that are given but wrong are a user
error (MissingWeightsError), never a silent skip. The default params read ``$GO_SD15_PATH``,
``$GO_CONTROLNET_TILE_PATH``, ``$GO_CLIP_PATH`` and ``$GO_SD15_CONFIG`` (expanded by the runner, so they are
part of the cache key).

Output: ``weights.json`` ``{"status": "ok" | "missing", "reason", "paths": {sd15, controlnet, clip,
single_file_config}}``.
"""

from __future__ import annotations

import json
from pathlib import Path

from go_core.errors import MissingWeightsError
from go_core.io.atomic import atomic_write_json

VERSION = "1"


def run(ctx, inputs: dict[str, Path], params: dict) -> None:
    from go_core.diffusion.models import WeightPaths, missing_weights

    paths = WeightPaths.resolve(params, env={})  # the runner already expanded ${ENV} defaults
    problems = missing_weights(paths)
    if problems and (paths.sd15 or paths.controlnet):
        raise MissingWeightsError("repair model weights: " + " | ".join(problems))
    if problems:
        reason = "repair model weights missing: " + " | ".join(problems)
        info = {"status": "missing", "reason": reason, "paths": paths.describe()}
        ctx.record(status="skipped", reason=reason)
        ctx.log.warning("%s; the result will be the coarse model", reason)
    else:
        info = {"status": "ok", "reason": "", "paths": paths.describe()}
        ctx.record(status="ok")
    atomic_write_json(Path(ctx.out_dir) / "weights.json", info)


def weight_paths(inputs: dict[str, Path]):
    """The checked ``WeightPaths`` from the weights step's artifact."""
    from go_core.diffusion.models import WeightPaths

    info = json.loads((Path(inputs["weights"]) / "weights.json").read_text())
    return WeightPaths(**info["paths"])
