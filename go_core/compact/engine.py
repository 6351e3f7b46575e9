"""The compact restorer behind the repair loop's model interface (one pass per view, no sampling)."""

from __future__ import annotations

import torch

from go_core.compact.restorer import CompactRestorer


class CompactRepair:
    """The compact model's side of the repair interface (``restore``, as ``RepairDiffusion.restore``)."""

    def __init__(self, restorer: CompactRestorer, device: str = "cpu") -> None:
        self.restorer = restorer.to(device).eval()
        self.device = device

    @property
    def channels(self) -> int:
        """3: the restorer takes RGB on white; 4: a repair prior, RGB and alpha (the repair loop's input)."""
        return int(getattr(self.restorer, "channels", 3))

    @staticmethod
    def square_side(settings) -> int:
        """The side of the square views the repair loop gives ``restore``: ``compact_resolution``."""
        return int(settings.compact_resolution)

    @staticmethod
    def lpips_weight(settings) -> float:
        """The repair loss's LPIPS weight with this model: ``compact_lpips``."""
        return float(settings.compact_lpips)

    def restore(self, square: torch.Tensor, rng, generator, settings) -> tuple[torch.Tensor, int, float]:
        """One repaired view for the repair loop: (images, label, w) with a blend strength b drawn from
        ``settings.strength_range`` (its one-pass t: label = 1000 b) and the weight w = b."""
        b = float(rng.uniform(*settings.strength_range))
        return self.repair_one_pass(square, b), round(1000 * b), b

    @torch.no_grad()
    def repair_one_pass(self, square: torch.Tensor, strength: float) -> torch.Tensor:
        """render + strength · (restore(render) − render), in [0, 1]."""
        restored = self.restorer.restore(square)
        square = square[:, : restored.shape[1]]  # a prior's reference channels are input only
        return (square + float(strength) * (restored - square)).clamp(0.0, 1.0)
