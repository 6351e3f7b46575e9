"""The diffusion-based repair model: local weight loading, LoRA, image framing and the SDEdit/DDIM sampler."""

from go_core.diffusion.models import (
    RepairModels,
    WeightPaths,
    load_repair_models,
    missing_weights,
    require_weights,
)

__all__ = ["RepairModels", "WeightPaths", "load_repair_models", "missing_weights", "require_weights"]
