"""noise_pairs: the 3D-noise configuration for repair-model tuning, and a preview of noise pairs.

Noise pairs are generated on the fly during the ``tune`` step (Algorithm 1: with probability p_manual a
fresh render of the coarse model with 3D noise on position, scale, rotation and opacity, never SH, drawn
from the leave-one-out statistics; p_manual starts at ``p0`` and is multiplied by ``decay`` per noise pair
used). This step fixes that configuration in ``noise_pairs.json`` (statistics, schedule, noise scale) and
writes ``preview.png``: one row per reference view: photo on white | coarse render | noisy render.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from go_core import artifacts as art
from go_core.io.atomic import atomic_write
from go_core.io.images import thumbnail
from go_core.repair.data import on_white, render_rgb_alpha, to_uint8, training_views
from go_core.repair.noise import NoiseStats
from go_core.repair.pairs import noise_pair
from go_core.seeding import torch_generator

if TYPE_CHECKING:
    from go_pipeline.steps.params import NoisePairsParams


def run(ctx, inputs: dict[str, Path], params: NoisePairsParams) -> None:
    loo = art.read_json(inputs["loo"], art.LOO_INFO)
    stats = NoiseStats.from_json(loo["stats"])
    coarse = art.read_gaussians(inputs["coarse"])
    _, views = training_views(inputs["scene"], inputs.get("mask"), inputs["coarse"])
    backend = params.backend
    scale = params.noise_scale
    config = {
        "status": "ok",
        "stats": stats.to_json(),
        "p0": params.p0,
        "decay": params.decay,
        "noise_scale": scale,
        "attributes": ["means", "log_scales", "quats", "opacity_logits"],
        "loo_pairs": len(loo.get("pairs", [])),
    }
    rows = []
    size = params.preview_size
    if size > 0:
        gen = torch_generator(int(ctx.seed), "noise_pairs_preview")
        for k, v in enumerate(views):
            pair = noise_pair(coarse, stats, v, k, gen, backend, scale)
            plain, _ = render_rgb_alpha(coarse, v.camera, 1.0, backend)
            imgs = [to_uint8(on_white(v.image, v.mask)), to_uint8(plain), to_uint8(pair.degraded)]
            row = np.concatenate([thumbnail(i, size) for i in imgs], axis=1)
            rows.append(row)
        width = max(r.shape[1] for r in rows)
        rows = [np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0)), constant_values=255) for r in rows]
        sheet = np.concatenate(rows, axis=0)

        def write(tmp: Path) -> None:
            from PIL import Image

            Image.fromarray(sheet).save(tmp, format="PNG")

        atomic_write(art.NOISE_PAIRS_PREVIEW.path(ctx.out_dir), write)
        config["preview"] = art.NOISE_PAIRS_PREVIEW.file
    art.write_json(ctx.out_dir, art.NOISE_PAIRS_INFO, config)
    ctx.record(p0=config["p0"], decay=config["decay"], loo_pairs=config["loo_pairs"], preview=size > 0)
