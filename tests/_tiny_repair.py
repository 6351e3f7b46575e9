"""Shared helpers for the repair tests: tiny random SD/ControlNet/CLIP weights, a synthetic object and a
step context (``one_thread`` is re-exported from tests._threads)."""

from __future__ import annotations

import json
from pathlib import Path

import torch

from go_pipeline.pipeline import step_params
from tests._threads import one_thread  # noqa: F401  (re-exported for the repair tests)

_BUILT: dict[str, dict[str, str]] = {}  # tiny weights already written in this test session (read-only use)


def tiny_weights(root: Path) -> dict[str, str]:
    """Params pointing at tiny random SD/ControlNet folders (written once per session, under ``root``)."""
    from go_core.diffusion.build import write_tiny_weights

    if "paths" in _BUILT and Path(_BUILT["paths"]["sd15_path"], "model_index.json").is_file():
        return dict(_BUILT["paths"])
    with one_thread():
        _BUILT["paths"] = write_tiny_weights(root, seed=0)
    return dict(_BUILT["paths"])


# A tiny synthetic object and a step context for end-to-end tests of the repair steps.


class FakeProgress:
    def __init__(self, total: int = 0, description: str = "") -> None:
        self.n = 0
        self.total, self.description = total, description
        self.fields: dict = {}

    def advance(self, n: int = 1, **fields) -> None:
        self.n += n
        self.fields.update(fields)

    def close(self) -> None:
        pass


class FakeCtx:
    """The StepContext protocol (steps/_api.py) without the runner."""

    def __init__(self, root: Path, step: str, seed: int = 0) -> None:
        import logging

        self.step = step
        self.out_dir = root / "out" / step
        self.checkpoint_dir = root / "ckpt" / step
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self.checkpoint_dir.mkdir(parents=True, exist_ok=True)
        self.seed = seed
        self.device = "cpu"
        self.log = logging.getLogger(f"test.{step}")
        self.records: dict = {}
        self.bars: list[FakeProgress] = []

    def progress(self, total: int, description: str = "", completed: int = 0) -> FakeProgress:
        bar = FakeProgress(total, description)
        bar.n = completed
        self.bars.append(bar)
        return bar

    def record(self, **values) -> None:
        self.records.update(values)


def _ring(prefix: str, azimuths, elevation: float, size: int):
    import numpy as np

    from go_core.camera import look_at

    K = np.array([[size * 0.9, 0.0, size / 2], [0.0, size * 0.9, size / 2], [0.0, 0.0, 1.0]])
    cams = []
    for i, az in enumerate(np.radians(azimuths)):
        el = np.radians(elevation)
        pos = 3.2 * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        cams.append(look_at(f"{prefix}_{i}", pos, np.zeros(3), np.array([0.0, 0.0, 1.0]), K, size, size))
    return cams


WEIGHT_KEYS = ("sd15_path", "controlnet_path", "clip_path", "single_file_config")


def weights_artifact(out: Path, status: str = "ok", paths: dict[str, str] | None = None) -> Path:
    """A ``weights`` step artifact as loo/noise_pairs read it (they look only at ``status``)."""
    import json

    out.mkdir(parents=True, exist_ok=True)
    names = {"sd15_path": "sd15", "controlnet_path": "controlnet", "clip_path": "clip"}
    described = {names.get(k, k): (paths or {}).get(k, "") for k in WEIGHT_KEYS}
    reason = "" if status == "ok" else "repair model weights missing (test)"
    info = {"status": status, "reason": reason, "paths": described}
    (out / "weights.json").write_text(json.dumps(info))
    return out


def run_weights_step(root: Path, params: dict) -> Path:
    """Run the real ``weights`` step on the weight-path keys of ``params``; returns its artifact dir."""
    from go_pipeline.steps import weights

    ctx = FakeCtx(root, "weights")
    chosen = {k: params[k] for k in ("repair_model", "compact_model") if k in params}
    values = {"repair_model": "sd15", **chosen, **{k: params.get(k, "") for k in WEIGHT_KEYS}}
    weights.run(ctx, {}, step_params(weights.__name__, values))
    return ctx.out_dir


def tiny_compact(cache_root: Path, name: str = "realesr-animevideov3-x4", seed: int = 0) -> Path:
    """A tiny SRVGGNetCompact-shaped x4 network (random weights) in the compact-model format, stored under
    ``name`` in the cache ``cache_root`` (point $GO_PIPELINE_CACHE at it)."""
    from safetensors.torch import save_file

    from go_core.compact.ncnn import NcnnNet, parse_param
    from go_core.compact.weights import compact_path

    param = "\n".join(
        [
            "7767517",
            "8 9",
            "Input in 0 1 data",
            "Split sp 1 2 data d0 d1",
            "Convolution c0 1 1 d1 a 0=8 1=3 4=1 5=1 6=216",
            "PReLU p0 1 1 a b 0=8",
            "Convolution c1 1 1 b c 0=48 1=3 4=1 5=1 6=3456",
            "PixelShuffle ps 1 1 c d 0=4",
            "Interp up 1 1 d0 e 0=1 1=4.0 2=4.0",
            "BinaryOp add 2 1 d e out",
        ]
    )
    layers = parse_param(param)
    torch.manual_seed(seed)
    net = NcnnNet(NcnnNet.spec_of(layers))
    with torch.no_grad():
        for p in net.parameters():
            p.mul_(0.1)
    path = compact_path(name, cache_root)
    path.parent.mkdir(parents=True, exist_ok=True)
    meta = {
        "format": "go-pipeline compact repair model 1",
        "name": name,
        "source": "test",
        "wheel_sha256": "",
        "licence": "",
        "scale": "4",
        "prepad": "0",
        "spec": json.dumps(NcnnNet.spec_of(layers)),
    }
    save_file({k: v.contiguous() for k, v in net.ncnn_tensors().items()}, str(path), metadata=meta)
    return path


def synthetic_inputs(root: Path, size: int = 64, n: int = 150) -> dict[str, Path]:
    """Scene, mask, hull and coarse artifacts (4 train + 2 test views of a coloured blob) in ``root``."""
    import numpy as np

    from go_core.gaussians import Gaussians
    from go_core.repair.data import render_rgb_alpha
    from go_core.scene.artifact import save_scene_artifact
    from go_core.scene.masking import save_masks
    from go_core.scene.types import Scene, View

    g = torch.Generator().manual_seed(0)
    pts = torch.randn(n, 3, generator=g)
    pts = 0.6 * pts / pts.norm(dim=1, keepdim=True) * torch.rand(n, 1, generator=g) ** (1 / 3)
    truth = Gaussians.from_points(pts, (pts + 0.6) / 1.2, torch.full((n,), 0.12), 0.8, 1)

    def views(cams):
        out = []
        for c in cams:
            rgb, alpha = render_rgb_alpha(truth, c, 0.0, "auto")
            a = alpha.clamp(0, 1)
            straight = (rgb / a.clamp_min(1e-3)[..., None]).clamp(0, 1) * (a[..., None] > 1e-3)
            out.append(View(c, straight.numpy().astype(np.float32), a.numpy().astype(np.float32)))
        return out

    scene = Scene(
        root / "scene",
        "nerf",
        views(_ring("train", [30, 120, 210, 300], 20, size)),
        views(_ring("test", [75, 165], 40, size)),
    )
    dirs = {"scene": root / "scene", "mask": root / "mask", "hull": root / "hull", "coarse": root / "coarse"}
    dirs["weights"] = weights_artifact(root / "weights_ok", status="ok")
    save_scene_artifact(scene, dirs["scene"])
    save_masks(dirs["mask"], [v.mask for v in scene.train])
    hull = Gaussians.from_points(pts * 1.2, torch.full((n, 3), 0.5), torch.full((n,), 0.1), 0.1, 1)
    hull.save(dirs["hull"] / "gaussians.npz")
    coarse = truth.map(lambda t: t.clone())
    coarse.means.add_(0.05 * torch.randn(n, 3, generator=g))  # a slightly wrong "coarse" model
    coarse.save(dirs["coarse"] / "gaussians.npz")
    return dirs
