"""The optimisation loop: it fits, extra hooks compose, and a killed run resumes bit-identically."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from go_core.camera import look_at
from go_core.coarse.loop import CoarseConfig, NoDensify, TrainView, optimize
from go_core.config import SettingError
from go_core.gaussians import Gaussians
from go_core.io.checkpoint import CheckpointSpec
from go_core.render import render_gaussians

BACKEND = "cpu"
SIZE = 24


pytestmark = pytest.mark.usefixtures("single_thread")  # small tensors: one thread is faster


def _cameras(n=3):
    K = np.array([[30.0, 0, SIZE / 2], [0, 30.0, SIZE / 2], [0, 0, 1]])
    cams = []
    for i in range(n):
        a = 2 * np.pi * i / n
        pos = np.array([3 * np.cos(a), 3 * np.sin(a), 0.8])
        cams.append(look_at(f"v{i}", pos, np.zeros(3), np.array([0, 0, 1.0]), K, SIZE, SIZE))
    return cams


def _gt(seed=0, n=40) -> Gaussians:
    g = torch.Generator().manual_seed(seed)
    return Gaussians.from_points(
        torch.randn(n, 3, generator=g) * 0.3, torch.rand(n, 3, generator=g), torch.full((n,), 0.12), 0.8, 0
    )


def _views():
    gt = _gt()
    views = []
    with torch.no_grad():
        for cam in _cameras():
            out = render_gaussians(
                gt, cam.viewmat_tensor()[None], cam.K_tensor()[None], SIZE, SIZE, backend=BACKEND
            )
            alpha = out.alpha[0, ..., 0]
            rgb = out.rgb[0] / alpha.clamp_min(1e-6)[..., None]  # straight colour, like a photo's RGBA
            views.append(TrainView(cam, rgb.clamp(0, 1), alpha.clamp(0, 1)))
    return views


def _init(seed=1, n=30) -> Gaussians:
    g = torch.Generator().manual_seed(seed)
    return Gaussians.from_points(
        torch.randn(n, 3, generator=g) * 0.4, torch.full((n, 3), 0.5), torch.full((n,), 0.1), 0.1, 0
    )


def _tiny_config(iterations=40) -> CoarseConfig:
    return CoarseConfig(
        iterations=iterations,
        drop_gamma=0.0,  # plain 3DGS here (the regularisers: tests/test_regularizers.py)
        lambda_opacity=0.0,
        lambda_anisotropy=0.0,
        position_lr_init=3e-3,
        position_lr_final=3e-4,
        position_lr_max_steps=iterations,
        sh_increase_every=15,
        backend=BACKEND,
        densify_from=5,
        densify_until=35,
        densify_every=5,
        opacity_reset_every=20,
        densify_grad_threshold=1e-5,
        floater_every=10,
        floater_from=10,
        floater_until=30,
        log_every=5,
    )


def _psnr(g: Gaussians, views) -> float:
    errs = []
    with torch.no_grad():
        for v in views:
            out = render_gaussians(
                g,
                v.camera.viewmat_tensor()[None],
                v.camera.K_tensor()[None],
                SIZE,
                SIZE,
                background=torch.ones(3),
                backend=BACKEND,
            )
            gt = v.image * v.mask[..., None] + (1 - v.mask[..., None])
            errs.append(((out.rgb[0] - gt) ** 2).mean().item())
    return float(-10 * np.log10(np.mean(errs)))


def test_optimisation_fits_the_views_and_reports_counts():
    views = _views()
    init = _init()
    cfg = _tiny_config(100)
    cfg.opacity_reset_every = 0
    out, stats = optimize(init, views, cfg, generator=torch.Generator().manual_seed(0))
    assert _psnr(out, views) > _psnr(init, views) + 5.0
    assert out.sh_degree == 2 and stats.final_count == len(out)
    assert stats.densify["cloned"] + stats.densify["split"] > 0
    assert [p["step"] for p in stats.floater_passes] == [10, 20, 30]
    assert stats.floaters_removed == sum(p["removed"] for p in stats.floater_passes) > 0
    assert stats.loss_log[-1]["step"] == 100 and stats.iterations == 100


def test_hooks_compose_fixed_set_extra_loss_and_view_weights():
    views = _views()
    views[1].weight = 0.0
    seen: list[int] = []

    def extra(step, g, out, view, index):
        seen.append(index)
        return 1e-3 * g.log_scales.exp().sum()

    cfg = _tiny_config(9)
    out, stats = optimize(
        _init(),
        views,
        cfg,
        generator=torch.Generator().manual_seed(0),
        strategy=NoDensify(),
        extra_loss=extra,
        sample_view=lambda step, gen: step % 3,
    )
    assert len(out) == 30 and seen == [1, 2, 0] * 3
    assert stats.floaters_removed == 0 and stats.floater_passes == []  # 9 steps: the first pass is at 10


@pytest.mark.parametrize(
    "extra", [{}, {"color_correction": True, "color_lr": 0.01, "lambda_inside": 0.1}], ids=["plain", "real"]
)
def test_killed_run_resumes_bit_identically(tmp_path, extra):
    views = _views()
    cfg = replace(_tiny_config(40), **extra)
    ref, ref_stats = optimize(_init(), views, cfg, generator=torch.Generator().manual_seed(7))

    class Killed(Exception):
        pass

    def killer(step, info):
        if step == 27:
            raise Killed

    spec = CheckpointSpec(tmp_path / "ckpt", every=6)
    with pytest.raises(Killed):
        optimize(
            _init(),
            views,
            cfg,
            generator=torch.Generator().manual_seed(7),
            checkpoint=spec,
            on_progress=killer,
        )
    assert [p.name for p in (tmp_path / "ckpt").glob("*.pt")] == ["ckpt_0000024.pt"]
    # the resumed run gets a fresh generator with the same seed: the checkpoint restores its state
    out, stats = optimize(_init(), views, cfg, generator=torch.Generator().manual_seed(7), checkpoint=spec)
    assert stats.resumed_from == 24
    for name, t in ref.tensors().items():
        assert torch.equal(getattr(out, name), t), name
    assert stats.loss_log == ref_stats.loss_log and stats.densify == ref_stats.densify
    assert stats.color_transforms == ref_stats.color_transforms  # the colour transforms resume too
    assert (stats.color_transforms is None) == (not extra)
    a, b = tmp_path / "a.npz", tmp_path / "b.npz"
    ref.save(a)
    out.save(b)
    with np.load(a) as x, np.load(b) as y:
        assert all(np.array_equal(x[k], y[k]) for k in x.files)


def test_config_from_flat_settings_is_checked():
    cfg = CoarseConfig.from_dict(
        {"iterations": 123, "floaters": False, "floater_schedule": "paper", "max_gaussians": 5,
         "feature_lr": 0.01, "lambda_depth": 0}
    )  # fmt: skip
    assert cfg.iterations == 123 and not cfg.floaters and cfg.floater_schedule == "paper"
    assert cfg.max_gaussians == 5 and cfg.feature_rest_lr == pytest.approx(0.0005) and cfg.lambda_depth == 0.0
    assert isinstance(cfg.lambda_depth, float)
    for bad, message in (
        ({"floater_schedule": "nope"}, "floater_schedule: must be one of 'code' | 'paper'"),
        ({"unknown": 1}, "unknown: unknown setting"),
        ({"iterations": -5}, "iterations: must be >= 0, got -5"),
        ({"iterations": 1.5}, "iterations: expected int, got float 1.5"),
    ):
        with pytest.raises(SettingError, match=message):
            CoarseConfig.from_dict(bad)


def test_depth_prior_term_enters_the_loss_with_gradients():
    from go_core.coarse.loop import view_loss

    views = _views()
    v = views[0]
    g = _gt().map(lambda t: t.clone().requires_grad_(True))
    cfg = _tiny_config(1)
    cfg.lambda_depth = 1.0
    bg = torch.ones(3)
    out = render_gaussians(
        g,
        v.camera.viewmat_tensor()[None],
        v.camera.K_tensor()[None],
        SIZE,
        SIZE,
        background=bg,
        backend=BACKEND,
    )
    prior = torch.rand(SIZE, SIZE, generator=torch.Generator().manual_seed(0))
    with_depth = TrainView(v.camera, v.image, v.mask, prior)
    loss_d, parts_d = view_loss(out, with_depth, bg, cfg, 1)
    loss, parts = view_loss(out, v, bg, cfg, 1)
    assert "depth" in parts_d and "depth" not in parts
    assert loss_d.item() == pytest.approx(loss.item() + parts_d["depth"], rel=1e-5)
    (loss_d - loss).backward()
    assert g.means.grad is not None and g.means.grad.abs().sum().item() > 0


def test_cyclic_gc_is_paused_in_the_loop_collected_periodically_and_restored():
    """The loop turns Python's automatic cyclic collection off (its full passes cost ~1 ms per iteration)
    and collects the young generation every 100 steps instead; the caller's setting comes back, also after
    an exception."""
    import gc
    import weakref

    class Node:
        pass

    enabled_in_loop: list[bool] = []
    last_step = [0]
    freed_at: list[int] = []

    def progress(step, info):
        enabled_in_loop.append(gc.isenabled())
        last_step[0] = step
        if step == 1:  # a reference cycle: only the cyclic collector can free it
            a, b = Node(), Node()
            a.other, b.other = b, a
            weakref.finalize(a, lambda: freed_at.append(last_step[0]))

    assert gc.isenabled()
    cfg = _tiny_config(120)
    optimize(
        _init(),
        _views(),
        cfg,
        generator=torch.Generator().manual_seed(0),
        strategy=NoDensify(),
        on_progress=progress,
    )
    assert gc.isenabled() and enabled_in_loop == [False] * 120
    assert freed_at == [99]  # by the collection at the start of step 100, not only after the loop

    def failing(step, g, out, view, index):
        raise RuntimeError("boom")

    with pytest.raises(RuntimeError, match="boom"):
        optimize(
            _init(), _views(), _tiny_config(3), generator=torch.Generator().manual_seed(0), extra_loss=failing
        )
    assert gc.isenabled()
    gc.disable()
    try:
        optimize(_init(), _views(), _tiny_config(2), generator=torch.Generator().manual_seed(0))
        assert not gc.isenabled()
    finally:
        gc.enable()
