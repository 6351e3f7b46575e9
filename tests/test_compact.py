"""The compact repair model: ncnn parity, weights errors, per-scene tuning, resumable tune/repair steps."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from go_pipeline.pipeline import step_params
from tests._tiny_repair import FakeCtx, one_thread, run_weights_step, synthetic_inputs, tiny_compact

EXAMPLE_IMAGE = Path(__file__).resolve().parents[1] / "go_pipeline" / "examples" / "basket" / "train"
LOO = {"phase1_iterations": 12, "phase2_iterations": 6, "renders": 2, "checkpoint_every": 0}
# the tuning itself: no per-scene choice of a prior (tests/test_restorer_choice.py tests that)
LORA = {
    "compact_steps": 6,
    "compact_resolution": 64,
    "checkpoint_every": 2,
    "compact_lr": 1e-3,
    "prior_choice": "",
}
REPAIR = {
    "iterations": 10,
    "repair_iterations": 8,
    "refresh_every": 4,
    "views_per_arc": 2,
    "compact_resolution": 64,
    "checkpoint_every": 5,
    "consensus": False,  # the second model's phases are tested in test_repair_steps.py
}
COMPACT = {"repair_model": "compact"}


@pytest.fixture(autouse=True)
def _threads():
    with one_thread():
        yield


@pytest.fixture()
def tiny_cache(tmp_path, monkeypatch):
    root = tmp_path / "cache"
    tiny_compact(root)
    monkeypatch.setenv("GO_PIPELINE_CACHE", str(root))
    return root


@pytest.fixture(scope="module")
def upstream(tmp_path_factory):
    from go_pipeline.steps import loo, noise_pairs

    root = tmp_path_factory.mktemp("compact_steps")
    with one_thread():
        dirs = synthetic_inputs(root)
        ctx = FakeCtx(root, "loo")
        loo.run(ctx, dirs, step_params(loo.__name__, LOO))
        dirs["loo"] = ctx.out_dir
        ctx = FakeCtx(root, "noise_pairs")
        noise_pairs.run(ctx, dirs, step_params(noise_pairs.__name__, {"preview_size": 0}))
        dirs["noise_pairs"] = ctx.out_dir
    return root, dirs


def _tune(root: Path, dirs: dict, params: dict) -> FakeCtx:
    from go_pipeline.steps import tune

    weights = run_weights_step(root / "weights", COMPACT)
    ctx = FakeCtx(root, "tune")
    tune.run(ctx, {**dirs, "weights": weights}, step_params(tune.__name__, params))
    return ctx


def _repair(root: Path, dirs: dict, lora_dir: Path, params: dict) -> FakeCtx:
    from go_pipeline.steps import repair

    ctx = FakeCtx(root, "repair")
    repair.run(ctx, {**dirs, "tune": lora_dir}, step_params(repair.__name__, params))
    return ctx


def _repair_killed_then_resumed(root: Path, dirs: dict, tune_dir: Path, params: dict, monkeypatch):
    """The repair step killed right after its first checkpoint, then run again: (its ctx, saves seen)."""
    from go_core.io.checkpoint import Checkpoints

    original, calls = Checkpoints.save, []

    def save_then_die(*args, **kwargs):
        original(*args, **kwargs)
        calls.append(1)
        raise KeyboardInterrupt("simulated kill after the first repair checkpoint")

    monkeypatch.setattr(Checkpoints, "save", save_then_die)
    with pytest.raises(KeyboardInterrupt):
        _repair(root, dirs, tune_dir, params)
    monkeypatch.setattr(Checkpoints, "save", original)
    return _repair(root, dirs, tune_dir, params), calls


def _assert_same_gaussians(dir_a: Path, dir_b: Path) -> None:
    from go_core.gaussians import Gaussians

    a, b = Gaussians.load(dir_a / "gaussians.npz"), Gaussians.load(dir_b / "gaussians.npz")
    for name in ("means", "quats", "log_scales", "opacity_logits", "sh"):
        assert torch.equal(getattr(a, name), getattr(b, name)), name


# --- parity with the original runtime -------------------------------------------------------------------


def _ncnn_pair(name: str) -> tuple[Path, Path]:
    from go_core.compact.weights import ncnn_files

    param, binf = ncnn_files(name)
    if not param.is_file():
        pytest.skip(f"{param} missing: run `go-pipeline weights fetch` (keeps the original .param/.bin)")
    return param, binf


@pytest.mark.parametrize(
    "name", ["realesr-animevideov3-x4", "waifu2x-upconv7-photo-noise3-x2", "waifu2x-upconv7-photo-noise1-x2"]
)
def test_torch_port_matches_ncnn_runtime_on_a_photo(name):
    """The torch port of the .param/.bin (via the converted safetensors) equals ncnn's CPU output within
    2e-4 (float32 accumulation order; measured ~5e-6) on a 48x40 crop of the example's first photo."""
    ncnn = pytest.importorskip("ncnn", reason="the `ncnn` package is a dev extra (pip install -e '.[dev]')")
    from PIL import Image

    from go_core.compact.weights import load_compact

    param, binf = _ncnn_pair(name)
    photo = np.asarray(Image.open(sorted(EXAMPLE_IMAGE.glob("*.png"))[0]).convert("RGB"), np.float32) / 255.0
    h, w = photo.shape[:2]
    crop = np.ascontiguousarray(
        photo[h // 2 - 20 : h // 2 + 20, w // 2 - 24 : w // 2 + 24].transpose(2, 0, 1)
    )
    net, meta = load_compact(name)
    with torch.no_grad():
        ours = net(torch.from_numpy(crop)[None])[0].numpy()
    ref_net = ncnn.Net()
    ref_net.opt.use_vulkan_compute = False
    for flag in ("use_fp16_storage", "use_fp16_arithmetic", "use_fp16_packed", "use_packing_layout"):
        setattr(ref_net.opt, flag, False)
    ref_net.opt.num_threads = 1
    assert ref_net.load_param(str(param)) == 0 and ref_net.load_model(str(binf)) == 0
    ex = ref_net.create_extractor()
    ex.input(net.input_name, ncnn.Mat(crop))
    ret, out = ex.extract(net.output_name)
    ref = np.array(out)
    assert ret == 0 and ref.shape == ours.shape
    pad = 2 * meta["prepad"]  # upconv_7 consumes 7 px per side (the restorer pre-pads them)
    assert ours.shape == (3, (40 - pad) * meta["scale"], (48 - pad) * meta["scale"])
    assert np.abs(ours - ref).max() < 2e-4
    assert np.abs(ref).max() > 0.1  # a real image came out, not zeros


def test_ncnn_param_parser_reads_arrays_and_refuses_unknown_layers():
    from go_core.compact.ncnn import parse_param

    layers = parse_param(
        "7767517\n2 2\nInput in 0 1 x\nConvolution c 1 1 x y 0=4 1=3 5=1 6=108 9=2 -23310=1,0.100000\n"
    )
    assert layers[1].params[10] == [0.1] and layers[1].params[6] == 108
    with pytest.raises(ValueError, match="Softmax"):
        parse_param("7767517\n2 2\nInput in 0 1 x\nSoftmax s 1 1 x y\n")


# --- weights: one clear error, nothing half-written -----------------------------------------------------


@pytest.mark.parametrize("damage", ["missing", "partial", "corrupt"])
def test_bad_compact_weights_are_one_error_naming_file_and_fetch(tmp_path, monkeypatch, damage):
    from go_pipeline.steps import weights

    from go_core.compact.weights import compact_path
    from go_core.errors import MissingWeightsError

    root = tmp_path / "cache"
    path = tiny_compact(root)
    monkeypatch.setenv("GO_PIPELINE_CACHE", str(root))
    data = path.read_bytes()
    if damage == "missing":
        path.unlink()
    elif damage == "partial":
        path.write_bytes(data[: len(data) // 2])
    else:
        path.write_bytes(data[:8] + b"{garbage" + data[16:])
    ctx = FakeCtx(tmp_path, "weights")
    with pytest.raises(MissingWeightsError) as err:
        weights.run(ctx, {}, step_params(weights.__name__, {"repair_model": "compact"}))
    msg = str(err.value)
    assert str(compact_path("realesr-animevideov3-x4", root)) in msg and "go-pipeline weights fetch" in msg
    assert "\n" not in msg
    assert list(ctx.out_dir.iterdir()) == []  # nothing written


def test_auto_chooses_compact_without_sd_weights_and_records_its_hash(tmp_path, tiny_cache):
    import hashlib

    out = run_weights_step(tmp_path, {"repair_model": "auto"})
    info = json.loads((out / "weights.json").read_text())
    path = Path(info["compact"]["file"])
    assert info["status"] == "ok" and info["repair_model"] == "compact"
    assert info["compact"]["sha256"] == hashlib.sha256(path.read_bytes()).hexdigest()


# --- per-scene tuning ----------------------------------------------------------------------------------


@pytest.mark.parametrize("method", ["full", "lora"])
def test_tuning_lowers_the_loss_on_held_back_pairs(upstream, tmp_path, tiny_cache, method):
    """Tuned on noise pairs only, the restorer's L1 on the (never seen) leave-one-out pairs drops."""
    root, dirs = upstream
    params = {**LORA, "compact_steps": 40, "checkpoint_every": 0, "use_loo_pairs": False}
    ctx = _tune(tmp_path, dirs, {**params, "compact_method": method})
    held = json.loads((ctx.out_dir / "tune.json").read_text())["loo_pairs_l1"]
    assert held["pairs"] >= 4
    assert held["after"] < 0.95 * held["before"], held


@pytest.mark.parametrize("method", ["full", "lora"])
def test_killed_compact_lora_resumes_to_the_same_weights(upstream, tmp_path, tiny_cache, monkeypatch, method):
    from safetensors.torch import load_file

    from go_core.io.checkpoint import Checkpoints

    root, dirs = upstream
    params = {**LORA, "compact_method": method}
    full = _tune(tmp_path / "a", dirs, params)
    original, saved = Checkpoints.save_tensors, []

    def save_then_die(self, step, fingerprint, tensors, meta):
        original(self, step, fingerprint, tensors, meta)
        saved.append(step)
        if step == 4:
            raise KeyboardInterrupt("simulated kill after the step-4 checkpoint")

    monkeypatch.setattr(Checkpoints, "save_tensors", save_then_die)
    with pytest.raises(KeyboardInterrupt):
        _tune(tmp_path / "b", dirs, params)
    assert saved == [2, 4]
    monkeypatch.setattr(Checkpoints, "save_tensors", original)
    resumed = _tune(tmp_path / "b", dirs, params)
    assert resumed.records["resumed_from"] == 4 and full.records["resumed_from"] == 0
    a = load_file(str(full.out_dir / "compact.safetensors"))
    b = load_file(str(resumed.out_dir / "compact.safetensors"))
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    assert (full.out_dir / "tune.json").read_bytes() == (resumed.out_dir / "tune.json").read_bytes()
    first = load_file(str(tiny_cache / "compact" / "realesr-animevideov3-x4.safetensors"))
    assert any(not torch.equal(first[k], a[k]) for k in a)  # tuning moved the weights


def test_conv_lora_starts_as_the_identity_and_merges_exactly(tiny_cache):
    from go_core.compact.lora import add_conv_lora, merge_conv_lora
    from go_core.compact.restorer import CompactRestorer

    model = CompactRestorer.load("realesr-animevideov3-x4")
    x = torch.rand(1, 3, 32, 32, generator=torch.Generator().manual_seed(0))
    base = {k: v.clone() for k, v in model.net.ncnn_tensors().items()}
    with torch.no_grad():
        before = model(x)
    trainable = add_conv_lora(model.net, 4, seed=0)
    assert 0 < sum(p.numel() for p in trainable) < sum(v.numel() for v in base.values())
    with torch.no_grad():
        assert torch.equal(model(x), before)  # peft's B = 0 at init
    opt = torch.optim.Adam(trainable, lr=1e-2)
    for _ in range(3):
        loss = (model(x) - x).abs().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    with torch.no_grad():
        adapted = model(x)
    assert not torch.equal(adapted, before)
    merge_conv_lora(model.net)
    tuned = model.net.ncnn_tensors()
    assert tuned.keys() == base.keys()  # plain convolutions again: saved like a full fine-tune
    assert all(torch.equal(tuned[k], base[k]) for k in base if k.endswith((".bias", ".slope")))
    with torch.no_grad():
        torch.testing.assert_close(model(x), adapted, atol=1e-5, rtol=0)


# --- repair ---------------------------------------------------------------------------------------------


def test_compact_repair_runs_and_a_killed_run_resumes_bit_identical(
    upstream, tmp_path, tiny_cache, monkeypatch
):

    root, dirs = upstream
    lora_ctx = _tune(tmp_path / "l", dirs, LORA)
    full = _repair(tmp_path / "a", dirs, lora_ctx.out_dir, REPAIR)
    info = json.loads((full.out_dir / "repair.json").read_text())
    assert info["status"] == "ok" and info["repair_model"] == "compact" and info["lora"] == "fine-tuned"
    for v in info["last_views"]:  # one-pass: t is the blend strength x 1000, w = the strength
        assert 500 <= v["t"] <= 1000 and v["w"] == pytest.approx(v["t"] / 1000, abs=1e-3)
        assert v["lambda"] > 0

    resumed, calls = _repair_killed_then_resumed(tmp_path / "b", dirs, lora_ctx.out_dir, REPAIR, monkeypatch)
    assert calls and resumed.records["resumed_from"] == 5
    _assert_same_gaussians(full.out_dir, resumed.out_dir)
    assert (full.out_dir / "repair.json").read_bytes() == (resumed.out_dir / "repair.json").read_bytes()


def test_pretrained_ablation_and_sds_refusal(upstream, tmp_path, tiny_cache):
    from go_core.errors import GoError

    root, dirs = upstream
    ctx = _tune(tmp_path / "p", dirs, {**LORA, "finetune": False})
    info = json.loads((ctx.out_dir / "tune.json").read_text())
    assert info["status"] == "pretrained" and info["repair_model"] == "compact"
    rep = _repair(tmp_path / "r", dirs, ctx.out_dir, REPAIR)
    assert json.loads((rep.out_dir / "repair.json").read_text())["lora"] == "pretrained (no fine-tuning)"
    with pytest.raises(GoError, match="sd15"):
        _repair(tmp_path / "s", dirs, ctx.out_dir, {**REPAIR, "loss": "sds"})


# --- a repair prior (issue 34) as the compact model: RGB + alpha through tuning and repair -------------


def _install_tiny_prior(tmp_path: Path, monkeypatch, reference: bool = False) -> Path:
    """A small, non-identity repair prior installed as the shipped prior ``tiny-prior`` (pinned SHA-256)."""
    import hashlib

    from go_core.compact import prior
    from go_core.seeding import seeded_torch_init

    with seeded_torch_init(0, "test_prior"):
        model = prior.RepairPrior(prior.PriorConfig(width=8, levels=2, reference=reference))
    with torch.no_grad():
        model.head.weight.normal_(0.0, 0.01, generator=torch.Generator().manual_seed(1))
    folder = tmp_path / "priors"
    path = prior.save_prior(folder / "tiny-prior.safetensors", model)
    monkeypatch.setattr(prior, "SHIPPED_DIR", folder)
    monkeypatch.setattr(prior, "SHIPPED", {"tiny-prior": hashlib.sha256(path.read_bytes()).hexdigest()})
    return path


@pytest.fixture()
def tiny_prior(tmp_path, monkeypatch):
    return _install_tiny_prior(tmp_path, monkeypatch)


@pytest.fixture(params=[False, True], ids=["no_reference", "reference"])
def tiny_prior_any(tmp_path, monkeypatch, request):
    """The tiny prior without and with the reference input (8 channels)."""
    return _install_tiny_prior(tmp_path, monkeypatch, request.param)


PRIOR = {"repair_model": "compact", "compact_model": "tiny-prior"}


def _tune_prior(root: Path, dirs: dict, params: dict) -> FakeCtx:
    from go_pipeline.steps import tune

    weights = run_weights_step(root / "weights", PRIOR)
    ctx = FakeCtx(root, "tune")
    tune.run(ctx, {**dirs, "weights": weights}, step_params(tune.__name__, params))
    return ctx


def test_leave_one_out_pairs_keep_the_render_alpha_for_a_prior(upstream):
    from go_core.gaussians import Gaussians
    from go_core.repair.data import render_rgb_alpha, training_views
    from go_core.repair.pairs import LooPairs, pair_tensors

    root, dirs = upstream
    loo = LooPairs(dirs["loo"])
    last = max(range(len(loo)), key=lambda i: (loo.pairs[i]["view"] == 0, loo.pairs[i]["phase2_step"]))
    pair = loo.get(last)  # run 0's render after phase 2: its model is the run's after.npz
    assert pair.degraded_alpha is not None and pair.degraded.shape[-1] == 3
    (after,) = root.rglob("run_00/after.npz")
    cam = training_views(dirs["scene"], dirs["mask"], dirs["coarse"])[1][0].camera
    _, alpha = render_rgb_alpha(Gaussians.load(after), cam, 1.0, "auto")
    torch.testing.assert_close(pair.degraded_alpha, (alpha * 255).round() / 255, atol=1 / 255 + 1e-6, rtol=0)
    deg, clean = pair_tensors(pair, 32, channels=4)
    assert deg.shape == clean.shape == (1, 4, 32, 32)
    rgb_deg, rgb_clean = pair_tensors(pair, 32)
    assert torch.equal(deg[:, :3], rgb_deg) and torch.equal(clean[:, :3], rgb_clean)
    # the target alpha is the clean view's mask: 0 where the clean photo is white background
    background = (rgb_clean[0] > 0.999).all(0)
    assert float(clean[0, 3][background].max()) < 0.05


def test_pair_alpha_is_framed_with_an_empty_background():
    """A wide view is padded to a square: the padding is white in RGB and 0 (no object) in alpha."""
    from go_core.repair.pairs import Pair, pair_tensors

    h, w = 16, 32
    mask = torch.zeros(h, w)
    mask[4:12, 2:30] = 1.0  # wider than the centred square: the frame pads to 32 x 32
    pair = Pair(torch.full((h, w, 3), 0.5), torch.full((h, w, 3), 0.25), mask, "noise", 0, mask.clone())
    deg, clean = pair_tensors(pair, 32, channels=4)
    assert torch.equal(deg[0, 3, :8], torch.zeros(8, 32)) and torch.equal(
        deg[0, :3, :8], torch.ones(3, 8, 32)
    )
    assert torch.equal(clean[0, 3, 8:24], mask)
    with pytest.raises(ValueError, match="alpha"):
        pair_tensors(Pair(pair.degraded, pair.clean, mask, "loo", 0), 32, channels=4)


def test_prior_restorer_is_one_module_for_any_size(tiny_prior):
    from go_core.compact.restorer import load_restorer

    model = load_restorer("tiny-prior")
    assert model.channels == 4 and model.scale == 1
    x = torch.rand(1, 4, 30, 22, generator=torch.Generator().manual_seed(0))
    y = model.restore(x)
    assert y.shape == x.shape and float(y.min()) >= 0 and float(y.max()) <= 1
    assert 0 < float((y - x).abs().max()) < 0.2  # a small, non-zero correction (head weights ~0.01)
    # padding to the U-Net's multiple is replicate: the crop of a padded input is the same as the original
    padded = torch.nn.functional.pad(x, (0, 2, 0, 2), mode="replicate")
    torch.testing.assert_close(model.restore(padded)[..., :30, :22], y, atol=0.2, rtol=0)


def test_shipped_prior_changed_on_disk_is_one_error_naming_it(tmp_path, tiny_prior):
    from go_pipeline.steps import weights

    from go_core.errors import MissingWeightsError

    out = run_weights_step(tmp_path / "ok", PRIOR)
    info = json.loads((out / "weights.json").read_text())["compact"]
    assert info["name"] == "tiny-prior" and info["scale"] == 1 and info["file"] == str(tiny_prior)
    data = bytearray(tiny_prior.read_bytes())
    data[-1] ^= 0xFF
    tiny_prior.write_bytes(bytes(data))
    ctx = FakeCtx(tmp_path / "bad", "weights")
    with pytest.raises(MissingWeightsError) as err:
        weights.run(
            ctx, {}, step_params(weights.__name__, {"repair_model": "compact", "compact_model": "tiny-prior"})
        )
    assert str(tiny_prior) in str(err.value) and "SHA-256" in str(err.value)
    tiny_prior.unlink()
    with pytest.raises(MissingWeightsError, match="missing"):
        weights.run(
            ctx, {}, step_params(weights.__name__, {"repair_model": "compact", "compact_model": "tiny-prior"})
        )


def _blob_pair(rng: np.random.Generator, size: int = 32):
    """A synthetic pair: a disc of one colour (the clean view) and its box-blurred, dimmed render with a
    dilated alpha (the degraded view), as a coarse model's render differs from the photo."""
    from go_core.repair.pairs import Pair

    yy, xx = np.mgrid[:size, :size]
    cy, cx, r = rng.uniform(10, 22, 2).tolist() + [float(rng.uniform(5, 9))]
    disc = ((yy - cy) ** 2 + (xx - cx) ** 2 < r**2).astype(np.float32)
    wide = ((yy - cy) ** 2 + (xx - cx) ** 2 < (r + 2) ** 2).astype(np.float32)
    clean = rng.uniform(0.1, 0.9, 3).astype(np.float32) * disc[..., None] + (1 - disc[..., None])
    blur = sum(np.roll(clean, k, axis=0) for k in range(-2, 3)) / 5.0
    degraded = np.clip(0.85 * blur + 0.1, 0, 1).astype(np.float32)
    t = torch.from_numpy
    return Pair(t(degraded), t(clean), t(disc), "noise", 0, t(wide))


def test_prior_tuning_lowers_its_rgb_and_alpha_loss_on_held_back_pairs(tiny_prior):
    """Tuned on synthetic (blurred, dilated) -> (sharp disc) pairs, the prior's 4-channel loss on other
    pairs of the same kind drops, in RGB and in alpha."""
    from go_core.compact.restorer import load_restorer
    from go_core.compact.tuning import CompactTuneSettings, held_out_loss, tune_compact
    from go_core.repair.noise import PairSchedule
    from go_core.repair.pairs import pair_tensors

    model = load_restorer("tiny-prior")
    held = [pair_tensors(_blob_pair(np.random.default_rng(100 + i)), 32, 4) for i in range(6)]
    alpha_err = lambda: float(np.mean([(model.restore(d)[:, 3] - c[:, 3]).abs().mean() for d, c in held]))  # noqa: E731
    before, alpha_before = held_out_loss(model, held), alpha_err()
    settings = CompactTuneSettings(steps=60, lr=3e-3, betas=(0.9, 0.999), resolution=32, checkpoint_every=0,
                                   method="full", rank=4)  # fmt: skip
    tune_compact(model, lambda rng, gen: _blob_pair(rng), PairSchedule(1.0, 0.995, False), settings, seed=0)
    assert held_out_loss(model, held) < 0.8 * before
    assert alpha_err() < 0.8 * alpha_before


def test_prior_tune_step_records_and_saves_the_tuned_prior(upstream, tmp_path, tiny_prior_any):
    from safetensors.torch import load_file

    root, dirs = upstream
    ctx = _tune_prior(tmp_path, dirs, LORA)
    info = json.loads((ctx.out_dir / "tune.json").read_text())
    assert info["status"] == "ok" and info["compact"]["name"] == "tiny-prior"
    assert np.isfinite([e["loss"] for e in info["loss_log"]]).all()
    tuned = load_file(str(ctx.out_dir / info["tuned"]))
    shipped = load_file(str(tiny_prior_any))
    assert tuned.keys() == shipped.keys()
    assert any(not torch.equal(tuned[k], shipped[k]) for k in shipped)


def test_prior_repair_uses_its_alpha_and_a_killed_run_resumes_bit_identical(
    upstream, tmp_path, tiny_prior_any, monkeypatch
):
    from go_core.gaussians import Gaussians

    root, dirs = upstream
    tuned = _tune_prior(tmp_path / "t", dirs, LORA)
    params = {**REPAIR, "alpha_weight": 1.0}
    full = _repair(tmp_path / "a", dirs, tuned.out_dir, params)
    info = json.loads((full.out_dir / "repair.json").read_text())
    assert info["compact_model"] == "tiny-prior" and info["lora"] == "fine-tuned"
    no_alpha = _repair(tmp_path / "n", dirs, tuned.out_dir, {**REPAIR, "alpha_weight": 0.0})
    a = Gaussians.load(full.out_dir / "gaussians.npz")
    assert not torch.equal(
        a.opacity_logits, Gaussians.load(no_alpha.out_dir / "gaussians.npz").opacity_logits
    )

    resumed, calls = _repair_killed_then_resumed(tmp_path / "b", dirs, tuned.out_dir, params, monkeypatch)
    assert calls
    _assert_same_gaussians(full.out_dir, resumed.out_dir)


def test_consensus_restorer_repairs_the_second_model_with_the_named_prior(
    upstream, tmp_path, tiny_cache, tiny_prior
):
    """repair.consensus_restorer: the second model's repair uses that compact model as shipped, not the
    run's own: the same second coarse fit, another repaired second model, recorded in repair.json."""
    from go_core import artifacts as art

    _, dirs = upstream
    tune_ctx = _tune(tmp_path / "t", dirs, {**LORA, "finetune": False})
    params = {**REPAIR, "consensus": True, "coarse": {"iterations": 20, "checkpoint_every": 8}}
    own = _repair(tmp_path / "own", dirs, tune_ctx.out_dir, params)
    named = {**params, "consensus_restorer": "tiny-prior"}
    prior = _repair(tmp_path / "prior", dirs, tune_ctx.out_dir, named)
    records = [json.loads((c.out_dir / "repair.json").read_text())["consensus"] for c in (own, prior)]
    assert [r["restorer"] for r in records] == ["own", "tiny-prior"]
    assert records[0]["coarse_gaussians"] == records[1]["coarse_gaussians"]
    second = [art.read_gaussians(c.checkpoint_dir / "consensus" / phase) for c in (own, prior) for phase in
              ("coarse", "repaired")]  # fmt: skip
    assert torch.equal(second[0].means, second[2].means)  # the same second coarse fit
    assert len(second[1]) != len(second[3]) or not torch.equal(second[1].means, second[3].means)


def test_inside_region_loss_against_hand_computed_values():
    """tune.compact_region inside: the RGB L1 only where the clean mask is (weighted by it), the alpha L1
    everywhere, in the proportions of the whole-view loss; refused for a 3-channel restorer."""
    from go_core.compact.tuning import pair_loss

    clean = torch.zeros(1, 4, 1, 2)
    clean[:, 3, 0, 0] = 1.0  # left pixel inside, right outside
    restored = torch.zeros(1, 4, 1, 2)
    restored[:, :3, 0, 0] = 0.2  # RGB error 0.2 inside ...
    restored[:, :3, 0, 1] = 0.6  # ... and 0.6 outside
    restored[:, 3, 0, 0] = 0.5  # alpha error 0.5 inside, 0 outside
    model = lambda x: x  # noqa: E731  (the "restorer" returns its input)
    whole = float(pair_loss(model, restored, clean))
    np.testing.assert_allclose(whole, (3 * (0.2 + 0.6) + 0.5) / 8, rtol=1e-6)
    inside = float(pair_loss(model, restored, clean, "inside"))
    np.testing.assert_allclose(inside, (3 * 0.2 + (0.5 + 0.0) / 2) / 4, rtol=1e-6)
    with pytest.raises(ValueError, match="compact_region"):
        pair_loss(model, restored[:, :3], clean[:, :3], "inside")
