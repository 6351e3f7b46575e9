"""Why Gaussians are pruned during the coarse stage: per densification interval, how many fall under each
prune rule (low opacity, screen size, world size, no contribution) and the quantiles of opacity and of the
largest screen radius seen. Written to find why real/ethiopian_head collapsed (issue 33,
benchmarks/results/real_collapse_probe.md).

    python benchmarks/archive/prune_reasons.py /path/to/scene /tmp/work [coarse_param=value ...] > log.txt
"""

from __future__ import annotations

import sys
from pathlib import Path

import torch

import go_core.coarse.densify as densify
from go_core import artifacts as art
from go_core.coarse.loop import TrainView, optimize
from go_core.seeding import torch_generator
from go_pipeline.runner import run_pipeline


def _quantiles(t: torch.Tensor, qs=(0.1, 0.5, 0.9)) -> list[float]:
    return [round(float(x), 4) for x in torch.quantile(t.float(), torch.tensor(qs))]


def _logging_prune_mask(original):
    def prune_mask(self, opt, step):
        c, p = self.config, opt.params
        opac = torch.sigmoid(p["opacity_logits"].detach())
        row = {"step": step, "n": len(opac), "low_opacity": int((opac < c.min_opacity).sum())}
        if step > c.opacity_reset_every > 0:
            row["screen"] = int((self.max_radii > self.screen_limit).sum())
            scale = p["log_scales"].detach().exp().max(1).values
            row["world"] = int((scale > c.max_world_size * self.extent).sum())
        row["no_contribution"] = int((self.color_grad == 0).sum())
        row["opacity_q10_50_90"] = _quantiles(opac)
        row["radius_px_q50_90_99"] = _quantiles(self.max_radii, (0.5, 0.9, 0.99))
        print(row, flush=True)
        return original(self, opt, step)

    return prune_mask


def main() -> None:
    scene_dir, work = Path(sys.argv[1]), Path(sys.argv[2])
    import yaml

    overrides = {f"coarse.{k}": yaml.safe_load(v) for k, v in (a.split("=", 1) for a in sys.argv[3:])}
    summary = run_pipeline(scene_dir, workdir=work, until="hull", overrides=overrides, quiet=True)
    from go_pipeline.pipeline import load_pipeline, step_params

    params = dict(load_pipeline().resolve_params(overrides=overrides)["coarse"])
    config = step_params("go_pipeline.steps.coarse", params).scaled_schedule()
    scene = art.read_scene(summary.step("scene").artifact_dir)
    masks = art.read_masks(summary.step("mask").artifact_dir, len(scene.train))
    pairs = zip(scene.train, scene.train_cameras, masks, strict=True)
    views = [TrainView.from_arrays(c, v.image, m) for v, c, m in pairs]
    densify.DensifyStrategy._prune_mask = _logging_prune_mask(densify.DensifyStrategy._prune_mask)
    init = art.read_gaussians(summary.step("hull").artifact_dir)
    print(
        {
            "screen_limit_px": densify.screen_size_limit(config, masks),
            "reset_every": config.opacity_reset_every,
        }
    )
    _, stats = optimize(init, views, config, generator=torch_generator(0))
    print({"final": stats.final_count, "densify": stats.densify, "floaters_removed": stats.floaters_removed})


if __name__ == "__main__":
    main()
