"""The compact restorer behind the repair loop's model interface (one pass per view, no sampling)."""

from __future__ import annotations

import torch

from go_core.compact.restorer import CompactRestorer


class CompactRepair:
    """What ``go_core.repair.repair.RepairCache`` calls for a one-pass repair model."""

    one_pass = True

    def __init__(self, restorer: CompactRestorer, device: str = "cpu") -> None:
        self.restorer = restorer.to(device).eval()
        self.device = device

    @torch.no_grad()
    def repair_one_pass(self, square: torch.Tensor, strength: float) -> torch.Tensor:
        """render + strength · (restore(render) − render), in [0, 1]."""
        restored = self.restorer.restore(square)
        return (square + float(strength) * (restored - square)).clamp(0.0, 1.0)
