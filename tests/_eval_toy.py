"""A toy pipeline around the REAL eval step (no tests here): a synthetic scene rendered from known
Gaussians, a "coarse" step that perturbs them, then ``go_pipeline.steps.eval``. Used by the eval, report
and batch tests. Scene folders hold ``seed.txt``; a non-number there makes the scene step fail."""

from __future__ import annotations

import sys
import textwrap
import uuid
from dataclasses import dataclass
from pathlib import Path

SCENE_STEP = """
from pathlib import Path

import numpy as np
import torch

from go_core.camera import look_at
from go_core.errors import SceneError
from go_core.gaussians import Gaussians
from go_core.render import render_gaussians
from go_core.scene.artifact import save_scene_artifact
from go_core.scene.types import Scene, View

VERSION = "1"


def truth(seed):
    g = torch.Generator().manual_seed(seed)
    n = 300
    pts = (torch.rand(n, 3, generator=g) - 0.5) * 1.2
    return Gaussians.from_points(pts, torch.rand(n, 3, generator=g), torch.full((n,), 0.08), 0.9, 0)


def cameras(size, count, elevation):
    K = np.array([[size * 1.4, 0, size / 2], [0, size * 1.4, size / 2], [0, 0, 1.0]])
    out = []
    for i in range(count):
        az = 2 * np.pi * (i + 0.25 * elevation) / count
        pos = np.array([3 * np.cos(az), 3 * np.sin(az), elevation])
        out.append(look_at(f"v{i}", pos, np.zeros(3), np.array([0, 0, 1.0]), K, size, size))
    return out


def view(g, cam):
    out = render_gaussians(g, cam.viewmat_tensor()[None], cam.K_tensor()[None], cam.width, cam.height)
    a = out.alpha[0, ..., 0].clamp(0, 1).numpy()
    rgb = (out.rgb[0].numpy() / np.maximum(a, 1e-6)[..., None]).clip(0, 1)  # straight colour
    return View(cam, rgb.astype(np.float32), a.astype(np.float32))


def run(ctx, inputs, params):
    path = Path(inputs["folder"]) / "seed.txt"
    try:
        seed = int(path.read_text().strip())
    except ValueError:
        raise SceneError("seed.txt is not an integer", path) from None
    g = truth(seed)
    size = params["size"]
    with torch.no_grad():
        train = [view(g, c) for c in cameras(size, 4, 0.8)]
        test = [view(g, c) for c in cameras(size, params["test_views"], 0.3)]
    save_scene_artifact(Scene(ctx.out_dir, "nerf", train, test), ctx.out_dir)
    g.save(ctx.out_dir / "truth.npz")
"""

COARSE_STEP = """
from pathlib import Path

import torch

from go_core.gaussians import Gaussians

VERSION = "1"


def run(ctx, inputs, params):
    g = Gaussians.load(Path(inputs["scene"]) / "truth.npz")
    gen = torch.Generator().manual_seed(ctx.seed)
    g.sh[:, 0] += params["color_noise"] * torch.randn(g.sh[:, 0].shape, generator=gen)
    g.save(ctx.out_dir / "gaussians.npz")
    ctx.record(num_gaussians=len(g), status="ok")
"""

PIPELINE = """
version: 1
steps:
  scene:
    function: {pkg}.scene:run
    inputs: {{folder: "@scene"}}
    outputs: [scene.json, views.npz, truth.npz]
    params: {{size: 40, test_views: 3}}
  coarse:
    function: {pkg}.coarse:run
    inputs: {{scene: scene}}
    outputs: [gaussians.npz]
    params: {{color_noise: 0.0}}
  eval:
    function: go_pipeline.steps.eval:run
    inputs: {{scene: scene, coarse: coarse}}
    outputs: [metrics.json, test_grid.png]
    params: {{lpips_nets: [vgg, alex], masked: false, backend: auto, grid_views: 8, thumb_size: 64}}
profiles: {{}}
"""


@dataclass
class EvalToy:
    pipeline: Path
    src: Path
    pkg: str

    def scene(self, root: Path, name: str, seed: str = "1") -> Path:
        d = root / name
        d.mkdir(parents=True)
        (d / "seed.txt").write_text(seed + "\n")
        return d


def make_eval_toy(tmp_path: Path) -> EvalToy:
    pkg = f"evaltoy_{uuid.uuid4().hex[:10]}"
    src = tmp_path / "src"
    (src / pkg).mkdir(parents=True)
    (src / pkg / "__init__.py").write_text("")
    (src / pkg / "scene.py").write_text(textwrap.dedent(SCENE_STEP).lstrip())
    (src / pkg / "coarse.py").write_text(textwrap.dedent(COARSE_STEP).lstrip())
    pipeline = tmp_path / "pipeline.yaml"
    pipeline.write_text(PIPELINE.format(pkg=pkg))
    if str(src) not in sys.path:
        sys.path.insert(0, str(src))
    return EvalToy(pipeline, src, pkg)
