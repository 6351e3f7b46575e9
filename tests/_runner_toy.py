"""A toy pipeline of tiny pure-Python steps for the runner and CLI tests (no torch, fast).

``make_toy_project(tmp_path)`` writes a package of step modules (one per step, each with its own VERSION),
a pipeline.yaml using them and a small scene folder, and returns their paths. The ``train`` step iterates
with a seeded RNG, checkpoints every few iterations and resumes from its newest checkpoint, like the real
training steps. This module holds no tests itself.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
import uuid
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

INGEST = """
import json
from pathlib import Path
from go_core.errors import SceneError
VERSION = "1"

def run(ctx, inputs, params):
    folder = Path(inputs["folder"])
    files = sorted(p for p in folder.glob("*.txt"))
    if not files:
        raise SceneError("no .txt files in the scene folder", folder)
    numbers = [float(x) * params["scale"] for p in files for x in p.read_text().split()]
    ctx.log.info(f"read {len(numbers)} numbers")
    if not params["skip_output"]:
        (ctx.out_dir / "data.json").write_text(json.dumps({"numbers": numbers}))
    ctx.record(count=len(numbers))
"""

DOUBLE = """
import json
from pathlib import Path
VERSION = "1"

def run(ctx, inputs, params):
    numbers = json.loads((Path(inputs["data"]) / "data.json").read_text())["numbers"]
    out = [x * params["factor"] for x in numbers]
    (ctx.out_dir / "doubled.json").write_text(json.dumps({"numbers": out}))
"""

SIDE = """
import json
from pathlib import Path
VERSION = "1"

def run(ctx, inputs, params):
    numbers = json.loads((Path(inputs["data"]) / "data.json").read_text())["numbers"]
    (ctx.out_dir / "side.json").write_text(json.dumps({"sum": sum(numbers), "label": params["label"]}))
    if params["skip"]:
        ctx.record(status="skipped", reason="label says skip")
"""

TRAIN = """
import json
import os
import random
import time
from pathlib import Path
VERSION = "1"

def _save_checkpoint(ckpt_dir, it, state, rng):
    tmp = ckpt_dir / f".ckpt-{it}.tmp"
    tmp.write_text(json.dumps({"it": it, "state": state, "rng": repr(rng.getstate())}))
    os.replace(tmp, ckpt_dir / f"ckpt-{it:06d}.json")
    for old in sorted(ckpt_dir.glob("ckpt-*.json"))[:-1]:
        old.unlink()

def run(ctx, inputs, params):
    numbers = json.loads((Path(inputs["data"]) / "doubled.json").read_text())["numbers"]
    rng = random.Random(ctx.seed)
    state, start = sum(numbers), 0
    found = sorted(ctx.checkpoint_dir.glob("ckpt-*.json"))
    if found:
        ck = json.loads(found[-1].read_text())
        start, state = ck["it"], ck["state"]
        rng.setstate(eval(ck["rng"]))
    ctx.record(resumed_from=start)
    bar = ctx.progress(params["iterations"], "iterations", completed=start)
    for it in range(start, params["iterations"]):
        if it == params["fail_at"]:
            raise RuntimeError(f"boom at iteration {it}")
        state = (state * 1.000001 + rng.random()) % 1000.0
        time.sleep(params["sleep"])
        bar.advance()
        if (it + 1) % params["checkpoint_every"] == 0:
            _save_checkpoint(ctx.checkpoint_dir, it + 1, state, rng)
    bar.close()
    (ctx.out_dir / "model.json").write_text(json.dumps({"state": repr(state)}))
"""

REPORT = """
import json
from pathlib import Path
VERSION = "1"

def run(ctx, inputs, params):
    model = json.loads((Path(inputs["model"]) / "model.json").read_text())
    data = json.loads((Path(inputs["data"]) / "data.json").read_text())
    n = len(data["numbers"])
    (ctx.out_dir / "report.txt").write_text(f"{params['title']}: {model['state']} over {n}\\n")
"""

PIPELINE = """
version: 1
steps:
  ingest:
    function: {pkg}.ingest:run
    inputs: {{folder: "@scene"}}
    outputs: [data.json]
    params: {{scale: 1.0, skip_output: false}}
  double:
    function: {pkg}.double:run
    inputs: {{data: ingest}}
    outputs: [doubled.json]
    params: {{factor: 2.0}}
  side:
    function: {pkg}.side:run
    inputs: {{data: ingest}}
    outputs: [side.json]
    params: {{label: "side", skip: false}}
  train:
    function: {pkg}.train:run
    inputs: {{data: double}}
    outputs: [model.json]
    params: {{iterations: 30, sleep: 0.0, checkpoint_every: 5, fail_at: -1, tags: [a, b], extra: null}}
  report:
    function: {pkg}.report:run
    inputs: {{model: train, data: ingest}}
    outputs: [report.txt]
    params: {{title: "toy"}}
profiles:
  quick:
    train: {{iterations: 10}}
  slow:
    train: {{iterations: 60, sleep: 0.02}}
"""

STEPS = {"ingest": INGEST, "double": DOUBLE, "side": SIDE, "train": TRAIN, "report": REPORT}


@dataclass
class ToyProject:
    root: Path
    pkg: str
    pipeline: Path
    scene: Path
    src: Path  # folder to put on sys.path / PYTHONPATH

    def step_file(self, step: str) -> Path:
        return self.src / self.pkg / f"{step}.py"

    def set_version(self, step: str, version: str) -> None:
        path = self.step_file(step)
        text = path.read_text()
        path.write_text(text.replace('VERSION = "1"', f'VERSION = "{version}"'))

    def env(self) -> dict[str, str]:
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join([str(self.src), str(REPO)] + sys.path[1:])
        return env

    def cli(self, *args: str, timeout: float = 60, check: bool = False) -> subprocess.CompletedProcess:
        """Run ``go-pipeline ARGS`` in a fresh interpreter with the toy package importable."""
        cmd = [sys.executable, "-m", "go_pipeline.cli", *args]
        return subprocess.run(
            cmd, env=self.env(), capture_output=True, text=True, timeout=timeout, check=check
        )


def make_toy_project(tmp_path: Path, scene_values: str = "1 2 3\n4 5\n") -> ToyProject:
    pkg = f"toysteps_{uuid.uuid4().hex[:10]}"
    src = tmp_path / "src"
    (src / pkg).mkdir(parents=True)
    (src / pkg / "__init__.py").write_text("")
    for name, code in STEPS.items():
        (src / pkg / f"{name}.py").write_text(textwrap.dedent(code).lstrip())
    pipeline = tmp_path / "pipeline.yaml"
    pipeline.write_text(PIPELINE.format(pkg=pkg))
    scene = tmp_path / "scene"
    scene.mkdir()
    (scene / "a.txt").write_text(scene_values)
    (scene / "b.txt").write_text("10\n")
    if str(src) not in sys.path:
        sys.path.insert(0, str(src))
    return ToyProject(tmp_path, pkg, pipeline, scene, src)


def content_hashes(workdir: Path) -> dict[str, str]:
    """step -> content hash of its current artifact."""
    from go_pipeline import store

    return {step: m["content_hash"] for step, m in store.current_manifests(workdir).items()}


def load_json(path: Path) -> dict:
    return json.loads(Path(path).read_text())
