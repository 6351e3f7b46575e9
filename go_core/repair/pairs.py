"""Degraded/clean training pairs for the repair model, drawn as in Algorithm 1 of the paper.

``PairSource.draw`` returns one pair per tuning step: with probability p_manual a fresh *noise pair* (the
coarse model with 3D noise, rendered at a random reference view, against that view's photo), else a cached
*leave-one-out pair* (a render of the left-out view against its photo). p_manual starts at 1 and is
multiplied by 0.995 every time a noise pair is used. All randomness comes from the generators passed in.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch

from go_core.diffusion.frame import Frame
from go_core.gaussians import Gaussians
from go_core.repair.data import framed_input, from_uint8, on_white, render_rgb_alpha
from go_core.repair.noise import NoiseStats, PairSchedule, add_noise


@dataclass
class Pair:
    degraded: torch.Tensor  # [H, W, 3] in [0, 1], on white
    clean: torch.Tensor  # [H, W, 3] in [0, 1], on white
    mask: torch.Tensor  # [H, W] object mask of the clean view (for framing)
    kind: str  # "noise" | "loo"
    view: int
    degraded_alpha: torch.Tensor | None = None  # [H, W] alpha of the degraded render (a prior's input)
    reference: tuple[torch.Tensor, torch.Tensor] | None = None  # a prior's reference input: RGB, alpha


def training_view_references(views: list, coarse: Gaussians, backend: str) -> list:
    """For each training view k, the reference input a prior gets with k's pairs: the nearest OTHER
    training view warped into k through the coarse model's expected depth at k ([H, W, 3], [H, W])."""
    from go_core.compact.reference import ReferenceViews
    from go_core.repair.data import render_rgb_alpha_depth

    refs = ReferenceViews(views)
    out = []
    for k, v in enumerate(views):
        _, alpha, depth = render_rgb_alpha_depth(coarse, v.camera, backend)
        rgb, a = refs.warp(v.camera, depth.numpy(), alpha.numpy(), exclude=k)
        out.append((torch.from_numpy(rgb), torch.from_numpy(a)))
    return out


def with_reference(pair: Pair, references: list) -> Pair:
    """``pair`` with the reference input of its view (``training_view_references``)."""
    return replace(pair, reference=references[pair.view])


def pair_tensors(pair: Pair, resolution: int, channels: int = 3) -> tuple[torch.Tensor, torch.Tensor]:
    """(degraded, clean) [1, C, r, r] in the clean view's square frame (what either repair model tunes on).
    ``channels`` 4 (a repair prior): RGB plus the degraded render's alpha, and the clean view's mask as the
    target alpha (framed with a 0 background); 8: the pair's reference RGB and alpha appended to degraded."""
    h, w = pair.clean.shape[:2]
    frame = Frame.choose(h, w, pair.mask)
    if channels == 3:
        return framed_input(frame, resolution, pair.degraded), framed_input(frame, resolution, pair.clean)
    if pair.degraded_alpha is None:
        raise ValueError(f"a {pair.kind} pair without the degraded render's alpha cannot tune a repair prior")
    if channels == 8 and pair.reference is None:
        raise ValueError(f"a {pair.kind} pair without its reference view cannot tune this repair prior")
    reference = pair.reference if channels == 8 else None
    return (
        framed_input(frame, resolution, pair.degraded, pair.degraded_alpha, reference),
        framed_input(frame, resolution, pair.clean, pair.mask.reshape(h, w)),
    )


def noise_pair(
    coarse: Gaussians,
    stats: NoiseStats,
    view,
    index: int,
    generator: torch.Generator,
    backend: str,
    scale: float,
) -> Pair:
    """The coarse model with 3D noise rendered at reference ``view`` (white background) vs. its photo."""
    noisy = add_noise(coarse, stats, generator, scale)
    rgb, alpha = render_rgb_alpha(noisy, view.camera, 1.0, backend)
    return Pair(rgb, on_white(view.image, view.mask), view.mask, "noise", index, alpha)


class LooPairs:
    """The leave-one-out pairs of a ``loo`` artifact (``loo.json`` + ``loo_pairs.npz``), held in memory."""

    def __init__(self, loo_dir: str | Path) -> None:
        loo_dir = Path(loo_dir)
        meta = json.loads((loo_dir / "loo.json").read_text())
        self.stats = NoiseStats.from_json(meta["stats"])
        self.pairs = meta.get("pairs", [])
        with np.load(loo_dir / "loo_pairs.npz", allow_pickle=False) as data:
            self.arrays = {k: data[k] for k in data.files}

    def __len__(self) -> int:
        return len(self.pairs)

    def get(self, i: int) -> Pair:
        p = self.pairs[i]
        degraded = from_uint8(self.arrays[p["degraded"]])  # RGB, or RGBA (the render's alpha kept too)
        return Pair(
            degraded[..., :3],
            from_uint8(self.arrays[p["clean"]]),
            from_uint8(self.arrays[p["mask"]]),
            "loo",
            int(p["view"]),
            degraded[..., 3] if degraded.shape[-1] == 4 else None,
        )


class PairSource:
    """Algorithm 1: noise pairs on the fly with probability p_manual, else cached leave-one-out pairs."""

    def __init__(
        self,
        coarse: Gaussians,
        stats: NoiseStats,
        views: list,
        loo: LooPairs | None,
        p0: float,
        decay: float,
        backend: str,
        noise_scale: float,
    ) -> None:
        self.coarse = coarse.detach()
        self.stats = stats
        self.views = views
        self.loo = loo if loo is not None and len(loo) > 0 else None
        self.schedule = PairSchedule(p0, decay, has_loo_pairs=self.loo is not None)
        self.backend = backend
        self.noise_scale = noise_scale

    def draw(self, rng: np.random.Generator, generator: torch.Generator) -> Pair:
        if self.schedule.draw(rng) == "noise":
            k = int(rng.integers(len(self.views)))
            return noise_pair(
                self.coarse, self.stats, self.views[k], k, generator, self.backend, self.noise_scale
            )
        return self.loo.get(int(rng.integers(len(self.loo))))
