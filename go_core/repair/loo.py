"""Leave-one-out runs (paper Sec. 3.4): how a model trained on too few views differs from a better one.

For each training view k: phase 1 trains the coarse model on the other N−1 views from the hull of all N
(with densification and floater removal, as the coarse stage); phase 2 continues with all N views, the set
kept fixed (no densification, no pruning) so that every Gaussian keeps its identity. Renders of view k during
phase 2 are degraded images whose clean counterpart is photo k; the per-Gaussian change of the parameters
from the end of phase 1 to the end of phase 2 feeds the 3D-noise statistics.

Every run persists into its own folder (phase checkpoints, ``before.npz``, renders, ``after.npz``, then
``done.json`` last), so a killed step resumes mid-run and never repeats a finished run. Runs are independent
and may execute in parallel processes.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from go_core.gaussians import Gaussians
from go_core.io.atomic import atomic_write, atomic_write_json
from go_core.repair.data import on_white, render_rgb_alpha, to_uint8
from go_core.repair.settings import LooSettings
from go_core.seeding import torch_generator


@dataclass
class LooRun:
    index: int
    name: str
    before: Gaussians
    after: Gaussians
    render_steps: list[int]
    renders: list[np.ndarray]  # uint8 [H, W, 4]: RGB on white and the alpha of the render
    info: dict


def render_steps(settings: LooSettings) -> list[int]:
    """Phase-2 steps whose (pre-update) state is rendered; the final state is added after the loop."""
    n = max(settings.renders - 1, 0)
    if n == 0 or settings.phase2_iterations <= 0:
        return []
    return sorted({int(s) for s in np.round(np.linspace(1, settings.phase2_iterations, n))})


def _save_npy(path: Path, a: np.ndarray) -> None:
    atomic_write(path, lambda tmp: np.save(open(tmp, "wb"), a))


def _phase1(
    init: Gaussians, others: list, settings: LooSettings, gen, run_dir: Path, extent: float, on_progress
):
    """Phase 1 of a leave-one-out run (the coarse model fitted without the left-out view), or its saved
    result and the generator's state after it when it already ran."""
    from go_core.coarse.loop import optimize
    from go_core.io.atomic import atomic_torch_save
    from go_core.io.checkpoint import CheckpointSpec, load_checkpoint

    before_path = run_dir / "before.npz"
    if before_path.is_file():
        gen.set_state(load_checkpoint(run_dir / "rng_after_phase1.pt"))  # a tensor: never code
        return Gaussians.load(before_path)
    before, stats1 = optimize(
        init,
        others,
        settings.phase1_config(),
        generator=gen,
        extent=extent,
        checkpoint=CheckpointSpec(run_dir / "phase1", every=settings.checkpoint_every),
        on_progress=on_progress,
    )
    atomic_torch_save(run_dir / "rng_after_phase1.pt", gen.get_state())
    before.save(before_path)
    atomic_write_json(
        run_dir / "phase1.json", {"final_count": stats1.final_count, "loss_log": stats1.loss_log[-3:]}
    )
    return before


def run_one(
    index: int,
    views: list,
    init: Gaussians,
    settings: LooSettings,
    seed: int,
    run_dir: Path,
    extent: float,
    on_progress=None,
    shown=None,
) -> LooRun:
    """Run (or resume, or just load) the leave-one-out run for view ``index``. ``on_progress(step, info)``
    after each iteration, counting phase 1 then phase 2 (``optimize``'s info: loss, n, ...). ``shown``: the
    left-out view at the size its renders and its clean photo are kept (default ``views[index]``; differs
    when the runs train on downscaled views, ``downscaled``)."""
    from go_core.coarse.loop import NoDensify, optimize
    from go_core.io.checkpoint import CheckpointSpec

    run_dir = Path(run_dir)
    done = run_dir / "done.json"
    if done.is_file():
        return load_run(run_dir)
    left = views[index] if shown is None else shown
    others = [v for i, v in enumerate(views) if i != index]
    gen = torch_generator(int(seed), "loo", index)
    info: dict = {"index": index, "name": left.camera.name}
    before = _phase1(init, others, settings, gen, run_dir, extent, on_progress)

    steps = set(render_steps(settings))
    rdir = run_dir / "renders"

    def save_render(step: int, g) -> None:  # the left-out view on white with its alpha, RGBA uint8
        rgb, alpha = render_rgb_alpha(g, left.camera, 1.0, settings.backend, settings.coarse.sh_degree)
        _save_npy(rdir / f"step_{step:07d}.npy", to_uint8(torch.cat([rgb, alpha[..., None]], -1)))

    def hook(step, g, out, view, i):
        if step in steps and not (rdir / f"step_{step:07d}.npy").is_file():
            save_render(step, g.detach())
        return None

    cfg2 = settings.phase2_config()
    if settings.phase2_iterations > 0:
        after, stats2 = optimize(
            before,
            views,
            cfg2,
            generator=gen,
            extent=extent,
            strategy=NoDensify(),
            extra_loss=hook,
            start_sh_degree=settings.coarse.sh_degree,
            checkpoint=CheckpointSpec(run_dir / "phase2", every=settings.checkpoint_every),
            on_progress=None
            if on_progress is None
            else lambda step, info: on_progress(settings.phase1_iterations + step, info),
        )
        info["phase2_final_loss"] = stats2.loss_log[-1]["loss"] if stats2.loss_log else None
    else:
        after = before
    if len(after) != len(before):
        raise AssertionError("phase 2 must keep the Gaussian set fixed")
    save_render(settings.phase2_iterations + 1, after)
    after.save(run_dir / "after.npz")
    clean = on_white(left.image, left.mask)
    _save_npy(run_dir / "clean.npy", to_uint8(clean))
    _save_npy(run_dir / "mask.npy", to_uint8(left.mask))
    info.update({"count": len(after), "settings": asdict(settings)})
    atomic_write_json(done, info)
    return load_run(run_dir)


def downscaled(views: list, max_size: int) -> list:
    """The training views with their long side at most ``max_size`` (area filter; 0: unchanged): the runs
    are cheaper to train, and the compact repair model sees their renders in 256-px frames downscaled 4x."""
    from go_core.coarse.loop import TrainView
    from go_core.scene.common import resize_view
    from go_core.scene.types import View

    out = []
    for v in views:
        if max_size <= 0 or max(v.camera.width, v.camera.height) <= max_size:
            out.append(v)
            continue
        if v.depth is not None:
            raise ValueError("downscaled: views with a depth prior are not supported")
        mask = None if v.mask is None else v.mask.numpy()
        small = resize_view(View(v.camera, v.image.numpy(), mask), max_size)
        out.append(
            TrainView.from_arrays(
                small.camera, small.image, small.mask, weight=v.weight, mask_weight=v.mask_weight
            )
        )
    return out


def run_is_done(run_dir: Path) -> bool:
    """The run in ``run_dir`` finished (its last file is written)."""
    return (Path(run_dir) / "done.json").is_file()


def load_clean_and_mask(run_dir: Path) -> tuple[np.ndarray, np.ndarray]:
    """The left-out photo on white and its mask, uint8, as the run saved them."""
    run_dir = Path(run_dir)
    clean = np.load(run_dir / "clean.npy", allow_pickle=False)
    return clean, np.load(run_dir / "mask.npy", allow_pickle=False)


def load_run(run_dir: Path) -> LooRun:
    run_dir = Path(run_dir)
    info = json.loads((run_dir / "done.json").read_text())
    files = sorted((run_dir / "renders").glob("step_*.npy"))
    return LooRun(
        info["index"],
        info["name"],
        Gaussians.load(run_dir / "before.npz"),
        Gaussians.load(run_dir / "after.npz"),
        [int(f.stem.split("_")[1]) for f in files],
        [np.load(f, allow_pickle=False) for f in files],
        info,
    )


def run_job(job: dict) -> str:
    """Process-pool entry point (one leave-one-out run); returns the run folder."""
    torch.set_num_threads(int(job.get("threads", 1)))
    run_one(
        job["index"],
        job["views"],
        job["init"],
        job["settings"],
        job["seed"],
        Path(job["run_dir"]),
        job["extent"],
        shown=job.get("shown"),
    )
    return job["run_dir"]
