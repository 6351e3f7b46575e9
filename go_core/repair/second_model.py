"""The further models of the repair's consensus (issue 33): the coarse stage and the plain repair made again
from the same inputs with a seed derived from the run's (one per model), so
``repair_gaussians(consensus=...)`` can restore what independently fitted models all render
(go_core.repair.consensus).

Each phase keeps its result in its own folder under the caller's checkpoint folder (``coarse/``: Gaussians
and the cameras they were fitted with, as the coarse step writes them; ``repaired/``: the final Gaussians),
written last and atomically, so a killed run resumes at the phase it stopped in, and inside it at the loop's
newest checkpoint: the result is bit-identical to an uninterrupted run's.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from go_core import artifacts as art
from go_core.coarse.fit import CoarseInputs, fit_coarse
from go_core.coarse.settings import CoarseConfig
from go_core.diffusion.sampler import RepairDiffusion
from go_core.gaussians import Gaussians
from go_core.io.checkpoint import CheckpointSpec
from go_core.repair.data import repair_views
from go_core.repair.loss import LpipsFn
from go_core.repair.repair import repair_gaussians
from go_core.repair.settings import ConsensusMember, RepairSettings
from go_core.seeding import derive_seed

SEED_TAG = "consensus"  # derive_seed(run seed, SEED_TAG): the second model's seed


def member_tag(number: int) -> str:
    """The name of the consensus's model ``number`` (the run's own model is 1, the second model 2, ...): its
    seed is ``derive_seed(run seed, member_tag(number))`` and the step keeps its phases in a folder of that
    name ("consensus", "consensus-3", ...)."""
    if number < 2:
        raise ValueError(f"consensus model number {number}: the further models are 2, 3, ...")
    return SEED_TAG if number == 2 else f"{SEED_TAG}-{number}"


@dataclass(frozen=True)
class SecondModel:
    """The second model and what it is: its seed, its coarse and final Gaussian counts."""

    gaussians: Gaussians
    seed: int
    coarse_count: int
    member: ConsensusMember = "repaired"

    def summary(self) -> dict:
        return {
            "seed": self.seed,
            "member": self.member,
            "coarse_gaussians": self.coarse_count,
            "gaussians": len(self.gaussians),
        }


def _coarse_phase(
    folder: Path,
    inputs: CoarseInputs,
    config: CoarseConfig,
    seed: int,
    checkpoint_every: int,
    on_progress: Callable[[str, int, dict], None] | None,
) -> Path:
    """``folder`` holding the second coarse model (gaussians.npz, cameras.json), fitted unless it is there."""
    if art.GAUSSIANS.path(folder).is_file():
        return folder
    spec = CheckpointSpec(folder / "checkpoints", every=checkpoint_every)
    progress = None if on_progress is None else (lambda step, info: on_progress("coarse", step, info))
    gaussians, stats, cameras = fit_coarse(inputs, config, seed, spec, progress)
    art.write_cameras(folder, cameras, stats.pose_corrections, aligned=inputs.aligned)
    art.write_gaussians(folder, gaussians)  # last: its presence marks the phase done
    return folder


def second_model(
    inputs: CoarseInputs,
    coarse_config: CoarseConfig,
    coarse_checkpoint_every: int,
    diffusion: RepairDiffusion,
    settings: RepairSettings,
    seed: int,
    checkpoint_dir: Path,
    lpips: LpipsFn | None = None,
    on_progress: Callable[[str, int, dict], None] | None = None,
    member: ConsensusMember = "repaired",
    number: int = 2,
) -> SecondModel:
    """The consensus's model ``number`` (2: the second model) at ``derive_seed(seed, member_tag(number))``: a
    coarse fit of ``inputs`` with
    ``coarse_config``, then (``member`` "repaired") the plain repair with ``diffusion`` and ``settings``
    at the cameras that fit used (without the depth priors, as the repair step's views are); with
    ``member`` "coarse" the coarse fit is the second model. ``on_progress(phase, step, info)`` with phase
    "coarse" or "repair"."""
    seed_b = derive_seed(int(seed), member_tag(number))
    checkpoint_dir = Path(checkpoint_dir)
    coarse_dir = _coarse_phase(
        checkpoint_dir / "coarse", inputs, coarse_config, seed_b, coarse_checkpoint_every, on_progress
    )
    coarse = art.read_gaussians(coarse_dir)
    if member == "coarse":
        return SecondModel(coarse, seed_b, len(coarse), member)
    done = checkpoint_dir / "repaired"
    if not art.GAUSSIANS.path(done).is_file():
        views = repair_views(inputs.views, coarse_dir)
        progress = None if on_progress is None else (lambda step, info: on_progress("repair", step, info))
        repaired, _, _ = repair_gaussians(
            coarse, views, diffusion, settings, seed_b, checkpoint_dir / "repair", lpips, progress
        )
        art.write_gaussians(done, repaired)
    return SecondModel(art.read_gaussians(done), seed_b, len(coarse))


__all__ = ["SEED_TAG", "SecondModel", "member_tag", "second_model"]
