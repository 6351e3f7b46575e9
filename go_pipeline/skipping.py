"""Skips decided by the runner, without starting a step's worker process.

A step's rules (go_pipeline.pipeline.StepRules: the registry's declaration of a packaged step, or the
module constants of a step of your own) may name inputs (``skip_if_skipped = ("weights",)``): when one of
those inputs' artifacts recorded ``status: "skipped"``, the step has nothing to do, and the runner writes its
skipped artifact itself: each declared ``.json`` output is ``{"status": "skipped", "reason": ...}``, each
``.npz`` output an empty archive. The reason names the root cause once, shortly ("repair model weights
missing (see the weights step)"), so a run without weights prints the long "weights missing" message only
once, from the weights step. ``skip_if_empty`` ({param: reason}) skips a step while that param is empty.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from go_core.errors import PipelineError

EMPTY_NPZ = b"PK\x05\x06" + b"\x00" * 18  # a zip archive without members: np.load gives an empty NpzFile


def param_skip(skip_if_empty: Mapping[str, str], params: dict[str, Any]) -> dict[str, str] | None:
    """The record of a runner-decided skip when a param the step names in ``skip_if_empty`` ({param:
    reason}) is empty (e.g. the depth step without a depth model), else None."""
    for param, reason in skip_if_empty.items():
        if not params.get(param):
            return {"status": "skipped", "reason": reason, "worker": "none (skipped by the runner)"}
    return None


def foreign_params(skip_if_param: Mapping[str, Mapping[str, str]], params: dict[str, dict[str, Any]]) -> dict:
    """The other steps' params a step's ``skip_if_param`` ({"step.param": {value: reason}}) reads, with their
    values ({"repair.mode": "full"}): part of the step's cache key, so that its skipped and its real
    artifact never share a key."""
    out = {}
    for dotted in skip_if_param:
        step, param = dotted.split(".", 1)
        out[dotted] = (params.get(step) or {}).get(param)
    return out


def foreign_param_skip(
    skip_if_param: Mapping[str, Mapping[str, str]], params: dict[str, dict[str, Any]]
) -> dict[str, str] | None:
    """The record of a runner-decided skip when another step's param has a value that ``skip_if_param``
    names (the repair chain's root under repair.mode no_repair), else None."""
    for dotted, value in foreign_params(skip_if_param, params).items():
        reason = skip_if_param[dotted].get(str(value))
        if reason is not None:
            return {"status": "skipped", "reason": reason, "worker": "none (skipped by the runner)"}
    return None


def short_reason(reason: str) -> str:
    """The first clause of a skip reason ("repair model weights missing: sd15 ..." -> its part before ':')."""
    return str(reason).split(":", 1)[0].strip() or "skipped"


def cascade_skip(
    skip_if_skipped: tuple[str, ...], step_inputs: dict[str, str], done: dict[str, dict[str, Any]]
) -> dict[str, str] | None:
    """The record of a runner-decided skip when one of the inputs named in ``skip_if_skipped`` was skipped,
    else None. ``step_inputs``: input name -> upstream step; ``done``: upstream step -> its manifest."""
    for name in skip_if_skipped:
        up = step_inputs.get(name)
        record = (done.get(up) or {}).get("record") or {}
        if up is None or record.get("status") != "skipped":
            continue
        root = record.get("skip_root") or up
        root_reason = record.get("skip_root_reason") or short_reason(record.get("reason", ""))
        return {
            "status": "skipped",
            "reason": f"{root_reason} (see the {root} step)",
            "skip_root": root,
            "skip_root_reason": root_reason,
            "worker": "none (skipped by the runner)",
        }
    return None


def write_skipped_outputs(
    out_dir: Path, outputs: tuple[str, ...], record: dict[str, str], where: str
) -> None:
    """Write a skipped step's declared outputs into ``out_dir``."""
    for name in outputs:
        path = Path(out_dir) / name
        path.parent.mkdir(parents=True, exist_ok=True)
        if name.endswith(".json"):
            text = json.dumps({"status": "skipped", "reason": record["reason"]}, indent=2, sort_keys=True)
            path.write_text(text + "\n", encoding="utf-8")
        elif name.endswith(".npz"):
            path.write_bytes(EMPTY_NPZ)
        else:
            raise PipelineError(f"cannot write a skipped step's {name!r} (only .json and .npz)", where)
