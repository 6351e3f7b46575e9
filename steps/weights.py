"""weights: choose the repair model and find its weights before any repair work.

``repair_model``: ``sd15`` (SD1.5 + ControlNet-tile + optional CLIP, below), ``compact`` (a pretrained
one-pass restoration network converted by `go-pipeline weights fetch`, ``compact_model`` names it; see
go_core.compact) or ``auto`` (sd15 when its weights are configured and complete, else compact). With
compact, missing, partial or corrupt weights are one MissingWeightsError naming the file and the fetch
command (never a skip); the file's SHA-256 is recorded, so downstream cache keys follow the weights.

The sd15 path:

Runs first in the repair chain and costs nothing, so a scene without weights never pays for the leave-one-out
runs, noise pairs or tuning: those steps see ``weights.json`` ``{"status": "missing"}`` and skip with its
reason, and the result is the coarse model (the report says so). Paths that are given but wrong are a user
error (MissingWeightsError), never a silent skip. The default params read ``$GO_SD15_PATH``,
``$GO_CONTROLNET_TILE_PATH``, ``$GO_CLIP_PATH`` and ``$GO_SD15_CONFIG`` (expanded by the runner, so they are
part of the cache key).

Output: ``weights.json`` ``{"status": "ok" | "missing", "reason", "repair_model": "sd15" | "compact",
"paths": {sd15, controlnet, clip, single_file_config}, "compact": {name, file, sha256, scale, source}}``.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from go_core import artifacts as art
from go_core.errors import MissingWeightsError
from go_core.extras import require_extra

if TYPE_CHECKING:
    from go_pipeline.steps.params import WeightsParams


def compact_model_info(name: str) -> dict:
    """weights.json's record of the compact model ``name`` (name, file, sha256, scale, source); missing or
    corrupt weights: one MissingWeightsError naming the file."""
    import hashlib

    from go_core.compact.prior import SHIPPED, shipped_prior_path
    from go_core.compact.weights import MODELS, WHEELS, check_compact_weights

    if name in SHIPPED:  # a repair prior trained here and shipped in the package (docs/repair_prior.md)
        path = shipped_prior_path(name)  # one MissingWeightsError naming the file
        return {"name": name, "file": str(path), "sha256": SHIPPED[name], "scale": 1,
                "source": "go-pipeline repair prior (docs/repair_prior.md)"}  # fmt: skip
    path = check_compact_weights(name)  # one MissingWeightsError naming the file and the fetch command
    model = MODELS[name]
    return {
        "name": name,
        "file": str(path),
        "sha256": hashlib.sha256(path.read_bytes()).hexdigest(),
        "scale": model.scale,
        "source": f"{WHEELS[model.wheel].requirement} ({model.licence})",
    }


def run(ctx, inputs: dict[str, Path], params: WeightsParams) -> None:
    from go_core.diffusion.models import WeightPaths, missing_weights

    choice = params.repair_model
    paths = WeightPaths(  # the runner already expanded the ${ENV} defaults
        sd15=params.sd15_path,
        controlnet=params.controlnet_path,
        clip=params.clip_path,
        single_file_config=params.single_file_config,
    )
    problems = missing_weights(paths)
    if choice != "compact" and problems and (paths.sd15 or paths.controlnet):
        raise MissingWeightsError("repair model weights: " + " | ".join(problems))
    if params.chosen_model()[0] == "compact":  # auto: compact when no SD1.5 / ControlNet path is given
        compact = compact_model_info(params.compact_model)
        why = "chosen" if choice == "compact" else "auto: no SD1.5 + ControlNet weights configured"
        info = {"status": "ok", "reason": "", "repair_model": "compact", "compact": compact,
                "paths": paths.describe(), "choice": why}  # fmt: skip
        ctx.record(status="ok", repair_model="compact", compact_model=compact["name"], choice=why)
    elif problems:
        reason = "repair model weights missing: " + " | ".join(problems)
        info = {"status": "missing", "reason": reason, "repair_model": "sd15", "paths": paths.describe()}
        ctx.record(status="skipped", reason=reason)
        ctx.log.warning("%s; the result will be the coarse model", reason)
    else:
        require_extra("sd15", "the SD1.5 repair (weights.sd15_path / controlnet_path)")
        info = {"status": "ok", "reason": "", "repair_model": "sd15", "paths": paths.describe()}
        ctx.record(status="ok", repair_model="sd15")
    art.write_json(ctx.out_dir, art.WEIGHTS_INFO, info)


def repair_model(inputs: dict[str, Path]) -> str:
    """ "sd15" | "compact": the repair model the weights step chose."""
    return str(art.read_json(inputs["weights"], art.WEIGHTS_INFO).get("repair_model", "sd15"))


def compact_info(inputs: dict[str, Path]) -> dict:
    """The weights step's record of the compact model (name, file, sha256, ...)."""
    return dict(art.read_json(inputs["weights"], art.WEIGHTS_INFO)["compact"])


def weight_paths(inputs: dict[str, Path]):
    """The checked ``WeightPaths`` from the weights step's artifact."""
    from go_core.diffusion.models import WeightPaths

    return WeightPaths(**art.read_json(inputs["weights"], art.WEIGHTS_INFO)["paths"])
