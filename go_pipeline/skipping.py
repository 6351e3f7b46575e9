"""Skips decided by the runner, without starting a step's worker process.

A step module may declare ``SKIP_IF_SKIPPED = ("weights",)``: when one of those inputs' artifacts recorded
``status: "skipped"``, the step has nothing to do, and the runner writes its skipped artifact itself: each
declared ``.json`` output is ``{"status": "skipped", "reason": ...}``, each ``.npz`` output an empty archive.
The reason names the root cause once, shortly ("repair model weights missing (see the weights step)"), so a
run without weights prints the long "weights missing" message only once, from the weights step.
The declaration is read from the module's source with ``ast`` (no import), like ``VERSION``.
"""

from __future__ import annotations

import ast
import json
from functools import lru_cache
from pathlib import Path
from typing import Any

from go_core.errors import PipelineError

DECLARATION = "SKIP_IF_SKIPPED"
PARAM_DECLARATION = "SKIP_IF_EMPTY"  # {"param": "reason"}: skipped when that param is empty
EMPTY_NPZ = b"PK\x05\x06" + b"\x00" * 18  # a zip archive without members: np.load gives an empty NpzFile


@lru_cache(maxsize=128)
def _declared(module_file: str, name: str) -> Any:
    """The literal value a step module assigns to ``name`` at its top level (None when it does not)."""
    tree = ast.parse(Path(module_file).read_text(encoding="utf-8"), filename=module_file)
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(
            isinstance(t, ast.Name) and t.id == name for t in node.targets
        ):
            try:
                return ast.literal_eval(node.value)
            except ValueError:
                raise PipelineError(f"{name} must be a literal", module_file) from None
    return None


def skip_if_skipped(module_file: str) -> tuple[str, ...]:
    """The input names a step module declares in ``SKIP_IF_SKIPPED`` (empty when it declares none)."""
    value = _declared(module_file, DECLARATION)
    if value is None:
        return ()
    if not isinstance(value, tuple) or not all(isinstance(v, str) for v in value):
        raise PipelineError(f"{DECLARATION} must be a tuple of input names", module_file)
    return value


def param_skip(module_file: str, params: dict[str, Any]) -> dict[str, str] | None:
    """The record of a runner-decided skip when a param the module names in ``SKIP_IF_EMPTY`` is empty
    (e.g. the depth step without a depth model), else None."""
    value = _declared(module_file, PARAM_DECLARATION)
    if value is None:
        return None
    if not isinstance(value, dict) or not all(
        isinstance(k, str) and isinstance(v, str) for k, v in value.items()
    ):
        raise PipelineError(f"{PARAM_DECLARATION} must map param names to reasons", module_file)
    for param, reason in value.items():
        if not params.get(param):
            return {"status": "skipped", "reason": reason, "worker": "none (skipped by the runner)"}
    return None


def short_reason(reason: str) -> str:
    """The first clause of a skip reason ("repair model weights missing: sd15 ..." -> its part before ':')."""
    return str(reason).split(":", 1)[0].strip() or "skipped"


def cascade_skip(
    module_file: str, step_inputs: dict[str, str], done: dict[str, dict[str, Any]]
) -> dict[str, str] | None:
    """The record of a runner-decided skip when one of the declared inputs was skipped, else None.

    ``step_inputs``: input name -> upstream step; ``done``: upstream step -> its manifest."""
    for name in skip_if_skipped(module_file):
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
            raise PipelineError(
                f"{DECLARATION}: cannot write a skipped {name!r} (only .json and .npz)", where
            )
