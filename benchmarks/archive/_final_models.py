"""The final models of a ``repair_dev.py`` run (its JSON names each variant's repair artifact per scene),
loaded with what a geometry benchmark measures them against (shared by the scripts, which run as
``python benchmarks/archive/X.py``)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np


def add_model_arguments(parser, variant: str) -> None:
    """The arguments that name the final models: ``--data`` (the dev scenes), ``--models`` (a
    ``repair_dev.py`` JSON) and ``--variant`` (which of its variants, ``variant`` by default)."""
    parser.add_argument("--data", type=Path, required=True)
    parser.add_argument(
        "--models", type=Path, required=True, help="a repair_dev.py JSON: repair_dir per scene"
    )
    parser.add_argument("--variant", default=variant, help="which of its variants' final models")


def final_gaussians(models: Path, variant: str) -> dict[str, Path]:
    """Per scene of the ``repair_dev.py`` JSON ``models``: the ``gaussians.npz`` of ``variant``'s repair."""
    scenes = json.loads(Path(models).read_text())["scenes"]
    return {
        name: Path(s["variants"][variant]["repair_dir"]) / "gaussians.npz"
        for name, s in scenes.items()
        if variant in s["variants"]
    }


@dataclass
class FinalScene:
    """A dev scene and its final model: the training cameras and masks, the visual hull's box, the
    Gaussians (float32) and the ground-truth mesh."""

    scene: object
    cameras: list
    masks: list[np.ndarray]
    box: tuple[np.ndarray, np.ndarray]
    gaussians: object
    truth: object


def load_final(scene_dir: Path, gaussians: Path) -> FinalScene:
    import torch

    from go_core.coarse.hull import hull_bounds
    from go_core.gaussians import Gaussians
    from go_core.mesh.files import read_mesh_npz
    from go_core.scene.loader import load_scene

    scene = load_scene(scene_dir)
    cams, masks = scene.train_cameras, [v.mask for v in scene.train]
    box = hull_bounds(cams, masks, min_views=len(cams))
    g = Gaussians.load(gaussians).to(dtype=torch.float32)
    return FinalScene(scene, cams, masks, box, g, read_mesh_npz(scene_dir / "mesh_world.npz"))
