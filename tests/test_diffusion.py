"""Repair-model loading, configs, framing and the SDEdit/DDIM sampler (tiny random models)."""

from __future__ import annotations

import math

import pytest
import torch

from go_core.diffusion.configs import sd15_architecture
from go_core.diffusion.frame import Frame
from go_core.diffusion.models import WeightPaths, load_repair_models, missing_weights, require_weights
from go_core.diffusion.sampler import RepairDiffusion
from go_core.errors import MissingWeightsError
from tests._tiny_repair import tiny_weights


@pytest.fixture(scope="module")
def weights(tmp_path_factory):
    return tiny_weights(tmp_path_factory.mktemp("tiny_repair"))


pytestmark = pytest.mark.usefixtures("single_thread")  # small tensors: one thread is faster


def test_missing_weights_one_clear_message(tmp_path):
    with pytest.raises(MissingWeightsError) as err:
        require_weights(WeightPaths.resolve({}, env={}))
    msg = str(err.value)
    assert "Stable Diffusion 1.5" in msg and "control_v11f1e_sd15_tile" in msg
    assert "GO_SD15_PATH" in msg and "GO_CONTROLNET_TILE_PATH" in msg and "\n" not in msg
    # a folder that is not in the diffusers layout is named
    bad = tmp_path / "not_sd"
    bad.mkdir()
    problems = missing_weights(WeightPaths(sd15=str(bad), controlnet=str(bad)))
    assert len(problems) == 2 and all(str(bad) in p for p in problems)
    # a single file without the configs folder needs the configs
    single = tmp_path / "v1-5.safetensors"
    single.write_bytes(b"x")
    problems = missing_weights(WeightPaths(sd15=str(single), controlnet=str(single)))
    assert all("single_file_config" in p for p in problems)


def test_env_resolution_and_params_win():
    env = {"GO_SD15_PATH": "/env/sd", "GO_CONTROLNET_TILE_PATH": "/env/cn"}
    p = WeightPaths.resolve({"sd15_path": "/param/sd"}, env=env)
    assert p.sd15 == "/param/sd" and p.controlnet == "/env/cn" and p.clip == ""


def test_load_tiny_folder_layout(weights):
    m = load_repair_models(WeightPaths.resolve(weights, env={}))
    for module in m.modules().values():
        assert not any(p.requires_grad for p in module.parameters())
        assert not module.training
    ids = m.tokenizer("a photo of xxy5syt00").input_ids
    assert ids[0] == m.tokenizer.bos_token_id and ids[-1] == m.tokenizer.eos_token_id
    assert m.scheduler.config.num_train_timesteps == 1000


def test_sd15_architecture_matches_published_sizes():
    """The full-size configs used by the benchmark give the published parameter counts."""
    from diffusers import AutoencoderKL, ControlNetModel, UNet2DConditionModel
    from transformers import CLIPTextConfig, CLIPTextModel

    arch = sd15_architecture()
    with torch.device("meta"):
        counts = {
            "unet": sum(p.numel() for p in UNet2DConditionModel(**arch.unet).parameters()),
            "controlnet": sum(p.numel() for p in ControlNetModel(**arch.controlnet).parameters()),
            "vae": sum(p.numel() for p in AutoencoderKL(**arch.vae).parameters()),
            "text": sum(p.numel() for p in CLIPTextModel(CLIPTextConfig(**arch.text_encoder)).parameters()),
        }
    assert counts["unet"] == pytest.approx(859.52e6, rel=1e-3)
    assert counts["controlnet"] == pytest.approx(361.3e6, rel=3e-3)
    assert counts["vae"] == pytest.approx(83.65e6, rel=1e-3)
    assert counts["text"] == pytest.approx(123.06e6, rel=1e-3)


def test_frame_pad_and_crop_roundtrip():
    img = torch.rand(1, 3, 40, 60)
    pad = Frame.choose(40, 60)  # no mask: pad to 60x60
    assert (pad.side, pad.x0, pad.y0) == (60, 0, -10)
    sq = pad.to_square(img, 60, background=1.0)
    assert torch.all(sq[:, :, :10] == 1.0) and torch.equal(sq[:, :, 10:50], img)
    assert torch.equal(pad.from_square(sq, torch.zeros_like(img)), img)
    mask = torch.zeros(40, 60)
    mask[10:30, 20:40] = 1.0  # object inside the centred 40x40 square: centre crop
    crop = Frame.choose(40, 60, mask)
    assert (crop.side, crop.x0, crop.y0) == (40, 10, 0)
    mask[5, 2] = 1.0  # object touches the left border: pad instead
    assert Frame.choose(40, 60, mask).side == 60


def test_repair_runs_floor_50t_ddim_steps(weights):
    m = load_repair_models(WeightPaths.resolve(weights, env={}))
    d = RepairDiffusion(m)
    assert d.steps_for(0.5, 50) == 25 and d.steps_for(0.019, 50) == 1 and d.steps_for(0.999, 50) == 49
    calls = []
    orig = d.predict_noise
    d.predict_noise = lambda *a, **k: calls.append(int(a[1])) or orig(*a, **k)
    render = torch.rand(1, 3, 64, 64, generator=torch.Generator().manual_seed(0))
    out = d.repair(render, 0.3, torch.Generator().manual_seed(1), 50, 1.0)
    assert out.steps == math.floor(50 * 0.3) == len(calls)
    assert out.timestep == calls[0] == 281 and calls[-1] == 1  # DDIM timesteps 281, 261, ..., 1
    assert out.images.shape == render.shape and 0.0 <= out.images.min() and out.images.max() <= 1.0
    again = d.repair(render, 0.3, torch.Generator().manual_seed(1), 50, 1.0)
    assert torch.equal(out.images, again.images)  # deterministic for a seed


def test_sds_gradient_is_weighted_noise_residual(weights):
    """d(SDS loss)/d(latent) = w(t)·(ε̂ − ε), so the loss value is ½‖w(t)·(ε̂ − ε)‖²."""
    m = load_repair_models(WeightPaths.resolve(weights, env={}))
    d = RepairDiffusion(m)
    img = torch.rand(1, 3, 64, 64, generator=torch.Generator().manual_seed(0), requires_grad=True)
    loss, t = d.sds_loss(img, 0.4, torch.Generator().manual_seed(3))
    assert t == 400
    g = torch.Generator().manual_seed(3)
    with torch.no_grad():
        z0 = m.vae.encode(img * 2 - 1).latent_dist.mean * d.vae_scale
        noise = torch.randn(z0.shape, generator=g)
        tt = torch.tensor([400])
        eps = d.predict_noise(d.scheduler.add_noise(z0, noise, tt), tt, img, d.text_embeddings())
        w = 1.0 - float(d.scheduler.alphas_cumprod[400])
    assert float(loss.detach()) == pytest.approx(0.5 * float(((w * (eps - noise)) ** 2).sum()), rel=1e-5)
    loss.backward()
    assert img.grad is not None and float(img.grad.abs().sum()) > 0  # flows back through the VAE encoder
