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
