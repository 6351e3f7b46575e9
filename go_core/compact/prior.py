"""The repair prior (issue 34): a small U-Net that restores a coarse 3DGS render at a novel view.

Input [B, C, H, W]: the degraded render on white (3), its alpha (1) and, with ``reference`` set, a reference
view on white (3) and its alpha (1). Output: RGB on white [B, 3, H, W] = clamp(degraded + residual) and
alpha [B, 1, H, W] = sigmoid(logit(coarse alpha) + correction): the network predicts what to change, so
an untrained-to-identity start and a render that is already right cost nothing.

Layout (``PriorConfig``): pixel-unshuffle by 2 (the U-Net runs at half resolution: 4x fewer pixels),
``levels`` encoder stages of two 3x3 conv + SiLU with ``width·2^i`` channels and a stride-2 conv between
them, the mirror decoder with skip concatenation, and pixel-shuffle back to full resolution. H and W must be
multiples of 2^levels (256 is). Weights are a safetensors file with the config and its format in the metadata
(``save_prior`` / ``load_prior``); a missing, corrupt or mismatched file is one MissingWeightsError naming it.

``PriorRestorer`` puts a prior behind the compact restorer's interface (``go_core.compact.restorer``): one
tensor in, one out, but with 4 channels, RGB on white and alpha, so the repair loop and the per-scene tuning
hand it the render's alpha and get a repaired alpha back. The trained priors shipped with the package are
listed in ``SHIPPED`` with their SHA-256 (docs/repair_prior.md is their model card).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn

from go_core.errors import MissingWeightsError

FORMAT = "go-pipeline/repair-prior-1"
ALPHA_EPS = 1e-3
SHIPPED_DIR = Path(__file__).resolve().parent / "priors"
SHIPPED: dict[str, str] = {  # name -> SHA-256 of priors/<name>.safetensors (docs/repair_prior.md: model card)
    "go-repair-prior-1": "4cf3ccf7d787ad788485f36d0e0d60ca5faaefd4f186f386d560ffb2a774be51",  # + reference
    "go-repair-prior-1-noref": "2060472daeff223e42ff9360cccbf14d3c8a0c3f3a1c8ce4591a5c86ead5d2e2",
    # go-repair-prior-1 trained on to 8000 steps
    "go-repair-prior-2": "81018615ed46cfaae3284e0dba2fd8b5833c4a830439c298e46e3acf53c42643",
    # go-repair-prior-2 fine-tuned 1500 steps with the object's pixels weighted 4x in the RGB loss
    "go-repair-prior-3": "3819272d600582176598492299a20cfa9059702d170111723494fd108c7cc723",
    # go-repair-prior-3 fine-tuned 1500 steps, a quarter of the samples at the training views (identity)
    "go-repair-prior-4": "873c4018c6316f4967c154761c7edf4ee38ceebfa349df6f510e90975295d1a1",
    # go-repair-prior-4's chain (1-noref → 8000 steps → inside 4 → training views) without the reference
    "go-repair-prior-4-noref": "4d151e5c69b9980694132a5cd49e4b076661d2b8fc9d73c197204f12f3f2616d",
}


@dataclass(frozen=True)
class PriorConfig:
    width: int = 32
    levels: int = 3
    reference: bool = False  # a reference view (RGB + alpha) as 4 more input channels

    @property
    def in_channels(self) -> int:
        return 8 if self.reference else 4


def _block(cin: int, cout: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(cin, cout, 3, padding=1), nn.SiLU(), nn.Conv2d(cout, cout, 3, padding=1), nn.SiLU()
    )


class RepairPrior(nn.Module):
    def __init__(self, config: PriorConfig) -> None:
        super().__init__()
        self.config = config
        w, n = config.width, config.levels
        chans = [w * 2**i for i in range(n)]
        self.stem = _block(config.in_channels * 4, chans[0])
        self.down = nn.ModuleList(
            nn.Conv2d(chans[i], chans[i + 1], 3, stride=2, padding=1) for i in range(n - 1)
        )
        self.enc = nn.ModuleList(_block(chans[i + 1], chans[i + 1]) for i in range(n - 1))
        self.up = nn.ModuleList(nn.ConvTranspose2d(chans[i + 1], chans[i], 2, stride=2) for i in range(n - 1))
        self.dec = nn.ModuleList(_block(2 * chans[i], chans[i]) for i in range(n - 1))
        self.head = nn.Conv2d(chans[0], 4 * 4, 3, padding=1)  # 3 RGB + 1 alpha, x4 for the pixel shuffle
        nn.init.zeros_(self.head.weight)
        nn.init.zeros_(self.head.bias)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(rgb [B,3,H,W] in [0, 1], alpha [B,1,H,W] in (0, 1)) from the input channels (module docstring)."""
        h = self.stem(F.pixel_unshuffle(x * 2.0 - 1.0, 2))
        skips = [h]
        for down, enc in zip(self.down, self.enc, strict=True):
            h = enc(down(h))
            skips.append(h)
        for i in reversed(range(len(self.up))):
            h = self.dec[i](torch.cat([self.up[i](h), skips[i]], 1))
        out = F.pixel_shuffle(self.head(h), 2)
        rgb = (x[:, :3] + out[:, :3]).clamp(0.0, 1.0)
        alpha = torch.sigmoid(torch.logit(x[:, 3:4].clamp(ALPHA_EPS, 1 - ALPHA_EPS)) + out[:, 3:4])
        return rgb, alpha


def prior_input(
    rgb: torch.Tensor,
    alpha: torch.Tensor,
    ref_rgb: torch.Tensor | None = None,
    ref_alpha: torch.Tensor | None = None,
) -> torch.Tensor:
    """The network input [B, 4 or 8, H, W] from [B,3,H,W] / [B,1,H,W] tensors in [0, 1]."""
    parts = [rgb, alpha]
    if ref_rgb is not None:
        parts += [ref_rgb, ref_alpha]
    return torch.cat(parts, 1)


def save_prior(path: Path, model: RepairPrior, extra: dict | None = None) -> Path:
    """Write the weights (float32) with the config (and ``extra`` JSON-able facts) in the metadata."""
    from go_core.io.safetensors_file import write_safetensors

    meta = {"format": FORMAT, "config": json.dumps(asdict(model.config), sort_keys=True)}
    if extra:
        meta["extra"] = json.dumps(extra, sort_keys=True)
    tensors = {k: v.detach().float().contiguous().cpu() for k, v in model.state_dict().items()}
    return write_safetensors(path, tensors, meta)


def load_prior(path: Path) -> RepairPrior:
    """The prior stored at ``path``; MissingWeightsError naming the file when absent, corrupt or foreign."""
    from safetensors import SafetensorError
    from safetensors.torch import safe_open

    path = Path(path)
    if not path.is_file():
        raise MissingWeightsError("repair prior weights not found", path)
    try:
        with safe_open(str(path), framework="pt") as f:
            meta = f.metadata() or {}
            tensors = {k: f.get_tensor(k) for k in f.keys()}  # noqa: SIM118
        if meta.get("format") != FORMAT:
            raise MissingWeightsError(f"not a repair prior file (format {meta.get('format')!r})", path)
        model = RepairPrior(PriorConfig(**json.loads(meta["config"])))
        model.load_state_dict(tensors, strict=True)
    except (SafetensorError, OSError, ValueError, KeyError, RuntimeError, TypeError) as exc:
        raise MissingWeightsError(f"corrupt repair prior weights ({type(exc).__name__})", path) from None
    return model.eval()


def shipped_prior_path(name: str) -> Path:
    """The checked file of the shipped prior ``name``: MissingWeightsError naming it when it is absent or
    its SHA-256 is not the pinned one (a corrupt or replaced file)."""
    import hashlib

    path = SHIPPED_DIR / f"{name}.safetensors"
    if not path.is_file():
        raise MissingWeightsError("shipped repair prior missing (reinstall go-pipeline)", path)
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    if digest != SHIPPED[name]:
        raise MissingWeightsError(f"repair prior SHA-256 {digest} is not the pinned {SHIPPED[name]}", path)
    return path


class PriorRestorer(nn.Module):
    """A repair prior behind the compact restorer's interface: [B, C, H, W] in (RGB on white and alpha,
    C = 4; with the reference view's RGB and alpha appended, C = 8), [B, 4, H, W] out. Any H and W: the
    input is padded (replicate) to the U-Net's multiple, the output cropped back."""

    scale = 1

    def __init__(self, prior: RepairPrior, name: str = "") -> None:
        super().__init__()
        self.channels = prior.config.in_channels  # 4, or 8 with the reference view (RGB + alpha) appended
        self.prior = prior
        self.name = name
        self.multiple = 2**prior.config.levels

    @staticmethod
    def load(name: str) -> PriorRestorer:
        """The shipped prior ``name`` (MissingWeightsError when absent, corrupt or not the pinned file)."""
        return PriorRestorer(load_prior(shipped_prior_path(name)), name)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h, w = x.shape[-2:]
        m = self.multiple
        ph, pw = (-h) % m, (-w) % m
        xp = F.pad(x, (0, pw, 0, ph), mode="replicate") if ph or pw else x
        rgb, alpha = self.prior(xp)
        return torch.cat([rgb, alpha], 1)[..., :h, :w]

    def tuned_tensors(self) -> dict[str, torch.Tensor]:
        """The weights a per-scene tuning changes (all of them), for the tune step's file."""
        return {k: v.detach().contiguous() for k, v in self.prior.state_dict().items()}

    def load_tuned(self, tensors: dict[str, torch.Tensor]) -> None:
        self.prior.load_state_dict(tensors, strict=True)

    @torch.no_grad()
    def restore(self, x: torch.Tensor) -> torch.Tensor:
        """Inference in eval mode (outputs are in [0, 1] by construction)."""
        was = self.training
        self.eval()
        try:
            return self(x)
        finally:
            self.train(was)
