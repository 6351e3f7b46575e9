"""Small helpers shared by several steps (artifact conventions that span steps)."""

from __future__ import annotations

import json
from pathlib import Path


def final_model_path(inputs: dict[str, Path]) -> tuple[Path, str]:
    """The Gaussians a downstream step should use: the repaired set when the repair step produced one,
    else the coarse set. Returns (path to gaussians.npz, "repair" | "coarse")."""
    repair = inputs.get("repair")
    if repair is not None:
        info_path = Path(repair) / "repair.json"
        if info_path.exists() and json.loads(info_path.read_text()).get("status") == "ok":
            return Path(repair) / "gaussians.npz", "repair"
    return Path(inputs["coarse"]) / "gaussians.npz", "coarse"


def write_skipped(ctx, json_name: str, reason: str, **extra) -> None:
    """Finish a step honestly without doing its work: ``json_name`` says ``{"status": "skipped",
    "reason": ...}``, and the reason goes to the manifest (and so the report) and the log."""
    from go_core.io.atomic import atomic_write_json

    atomic_write_json(Path(ctx.out_dir) / json_name, {"status": "skipped", "reason": reason, **extra})
    ctx.record(status="skipped", reason=reason)
    ctx.log.warning("%s skipped: %s", ctx.step, reason)


def repair_weights_missing(inputs: dict[str, Path]) -> str | None:
    """Why the repair chain must skip (the ``weights`` step found no repair-model weights), or None."""
    info = json.loads((Path(inputs["weights"]) / "weights.json").read_text())
    return None if info["status"] == "ok" else str(info["reason"])
