"""Loading SD1.5 + ControlNet-tile from ORIGINAL single files (CompVis/LDM key layout), offline.

Tiny random diffusers models are written as LDM-layout ``.safetensors`` / ``.ckpt`` / ``.pth`` files
(tests/_ldm_layout.py) next to a folder holding only their diffusers configs + tokenizer, loaded back
through ``go_core.diffusion.models`` (diffusers' ``from_single_file``) and compared tensor by tensor with
the originals. The tiny UNet keeps SD1.5's topology (4 levels, 2 layers per level, transformers in the first
three down levels and last three up levels, 12 input / 12 output blocks) so every branch of the key
conversion runs.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from go_core.diffusion.models import WeightPaths, load_repair_models, missing_weights
from go_core.errors import MissingWeightsError
from tests._ldm_layout import CLIP_PREFIX, UNET_PREFIX, controlnet_single_file, sd15_single_file

pytestmark = pytest.mark.usefixtures("single_thread")  # small tensors: one thread is faster


def _tiny_sd15_architecture():
    """SD1.5 + ControlNet-tile topology at a few hundred thousand parameters."""
    from go_core.diffusion.configs import RepairArchitecture, sd15_architecture

    full = sd15_architecture()
    narrow = {
        "block_out_channels": [8, 16, 16, 16],
        "cross_attention_dim": 16,
        "attention_head_dim": 2,
        "norm_num_groups": 4,
    }
    unet = {**full.unet, **narrow, "sample_size": 8}
    controlnet = {**full.controlnet, **narrow, "conditioning_embedding_out_channels": [4, 4, 8, 8]}
    vae = {**full.vae, "block_out_channels": [4, 4, 8, 8], "norm_num_groups": 2, "sample_size": 32}
    text = {
        **full.text_encoder,
        "vocab_size": 600,
        "hidden_size": 16,
        "intermediate_size": 32,
        "num_hidden_layers": 2,
        "num_attention_heads": 2,
        "projection_dim": 16,
    }
    return RepairArchitecture(unet, controlnet, vae, text)


def _write_config_folder(models, cfg: Path) -> None:
    """Only configs + tokenizer (no weights), with SD1.5's own model_index.json entries."""
    import diffusers

    for name in ("unet", "vae", "controlnet"):
        getattr(models, name).save_config(cfg / name)
    models.text_encoder.config.save_pretrained(cfg / "text_encoder")
    models.tokenizer.save_pretrained(cfg / "tokenizer")
    models.scheduler.save_pretrained(cfg / "scheduler")
    index = {  # as in stable-diffusion-v1-5: safety checker and feature extractor listed, not downloaded
        "_class_name": "StableDiffusionPipeline",
        "_diffusers_version": diffusers.__version__,
        "feature_extractor": ["transformers", "CLIPImageProcessor"],
        "safety_checker": ["stable_diffusion", "StableDiffusionSafetyChecker"],
        "requires_safety_checker": True,
        "scheduler": ["diffusers", "PNDMScheduler"],
        "text_encoder": ["transformers", "CLIPTextModel"],
        "tokenizer": ["transformers", "CLIPTokenizer"],
        "unet": ["diffusers", "UNet2DConditionModel"],
        "vae": ["diffusers", "AutoencoderKL"],
    }
    (cfg / "model_index.json").write_text(json.dumps(index, indent=2))


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    import shutil

    from safetensors.torch import save_file

    from go_core.diffusion.build import build_random_models, tiny_tokenizer_files

    root = tmp_path_factory.mktemp("single_file")
    tok = tiny_tokenizer_files(root / "tok")
    models = build_random_models(_tiny_sd15_architecture(), seed=3, tokenizer_dir=tok)
    _write_config_folder(models, root / "config")
    shutil.copytree(root / "config", root / "config_no_scheduler", ignore=shutil.ignore_patterns("scheduler"))
    sd = sd15_single_file(models.unet, models.vae, models.text_encoder)
    cn = controlnet_single_file(models.controlnet)
    save_file(sd, root / "v1-5-pruned-emaonly.safetensors")
    save_file(cn, root / "control_v11f1e_sd15_tile.safetensors")
    torch.save({"global_step": 840000, "state_dict": sd}, root / "v1-5-pruned-emaonly.ckpt")
    torch.save(cn, root / "control_v11f1e_sd15_tile.pth")
    # broken files: not a weights file at all, and files lacking some tensors
    (root / "corrupt.safetensors").write_bytes(bytes(range(256)) * 8)
    (root / "corrupt.pth").write_bytes(bytes(range(256)) * 8)
    save_file(
        {k: v for k, v in sd.items() if ".input_blocks.4." not in k}, root / "no_unet_block.safetensors"
    )
    save_file({k: v for k, v in sd.items() if ".layers.1." not in k}, root / "no_clip_layer.safetensors")
    save_file({k: v for k, v in sd.items() if "first_stage" not in k}, root / "no_vae.safetensors")
    save_file({k: v for k, v in cn.items() if ".zero_convs.3." not in k}, root / "no_zero_conv.safetensors")
    return {"root": root, "models": models, "sd": sd, "cn": cn}


def _paths(tiny, sd15: str, controlnet: str, config: str = "config") -> WeightPaths:
    root = tiny["root"]
    return WeightPaths(
        sd15=str(root / sd15), controlnet=str(root / controlnet), single_file_config=str(root / config)
    )


def _assert_same_parameters(loaded, original, name: str) -> int:
    got, want = loaded.state_dict(), original.state_dict()
    assert sorted(got) == sorted(want), name
    for key, value in want.items():
        assert got[key].dtype == value.dtype and torch.equal(got[key], value), f"{name}.{key} differs"
    return len(want)


def test_ldm_file_has_original_key_layout(tiny):
    sd, cn = tiny["sd"], tiny["cn"]
    # names and shapes that only the original layout has
    assert sd[UNET_PREFIX + "input_blocks.1.1.proj_in.weight"].shape == (8, 8, 1, 1)
    assert UNET_PREFIX + "input_blocks.11.0.out_layers.3.weight" in sd  # 12 input blocks, as SD1.5
    assert UNET_PREFIX + "output_blocks.11.1.transformer_blocks.0.attn2.to_k.weight" in sd
    assert UNET_PREFIX + "output_blocks.2.1.conv.weight" in sd  # upsampler of a level without attention
    assert UNET_PREFIX + "output_blocks.5.2.conv.weight" in sd  # ... and after a transformer
    assert sd["first_stage_model.encoder.mid.attn_1.q.weight"].shape == (8, 8, 1, 1)
    assert sd["first_stage_model.decoder.up.1.block.0.nin_shortcut.weight"].shape == (4, 8, 1, 1)
    assert CLIP_PREFIX + "text_model.encoder.layers.1.mlp.fc2.weight" in sd
    assert cn["control_model.input_hint_block.14.weight"].shape == (8, 8, 3, 3)
    assert cn["control_model.zero_convs.11.0.weight"].shape == (16, 16, 1, 1)
    assert not any(k.startswith(("unet.", "down_blocks", "vae.")) for k in sd)
    n_tensors = sum(len(m.state_dict()) for m in (tiny["models"].unet, tiny["models"].vae))
    n_tensors += len(tiny["models"].text_encoder.state_dict())
    assert len(sd) == n_tensors + 3  # + position_ids, betas, alphas_cumprod


def test_safetensors_single_files_load_bit_for_bit(tiny):
    paths = _paths(tiny, "v1-5-pruned-emaonly.safetensors", "control_v11f1e_sd15_tile.safetensors")
    assert missing_weights(paths) == []
    m, ref = load_repair_models(paths), tiny["models"]
    counts = {
        name: _assert_same_parameters(getattr(m, name), getattr(ref, name), name) for name in ref.modules()
    }
    assert counts == {"unet": 684, "controlnet": 338, "vae": 244, "text_encoder": 36}
    assert m.tokenizer("a photo of xxy5syt00").input_ids == ref.tokenizer("a photo of xxy5syt00").input_ids
    assert type(m.scheduler).__name__ == "DDIMScheduler" and m.scheduler.config.num_train_timesteps == 1000

    # safetensors tensors are views into the mmapped file at unaligned addresses, which sends CPU kernels down
    # other SIMD paths (last-bit differences); in owned memory the forward passes must match bit for bit
    for module in m.modules().values():
        for p in module.parameters():
            p.data = p.data.clone()
    g = torch.Generator().manual_seed(0)
    latents = torch.randn(1, 4, 8, 8, generator=g)
    text = torch.randn(1, 5, 16, generator=g)
    hint = torch.rand(1, 3, 64, 64, generator=g)
    t = torch.tensor([500])
    with torch.no_grad():
        down, mid = m.controlnet(latents, t, text, controlnet_cond=hint, return_dict=False)
        down_ref, mid_ref = ref.controlnet(latents, t, text, controlnet_cond=hint, return_dict=False)
        assert len(down) == 12 and all(map(torch.equal, down, down_ref))
        assert torch.equal(mid, mid_ref)
        residuals = {"down_block_additional_residuals": down, "mid_block_additional_residual": mid}
        out = m.unet(latents, t, text, **residuals)
        want = ref.unet(latents, t, text, **residuals)
    assert out.sample.shape == (1, 4, 8, 8) and out.sample.abs().sum() > 0
    assert torch.equal(out.sample, want.sample)


def test_ckpt_and_pth_single_files_load_bit_for_bit(tiny):
    """torch.save forms: ``{"global_step", "state_dict"}`` for SD, a flat ``control_model.*`` dict for the
    ControlNet; with a configs folder without ``scheduler/`` (SD1.5's DDIM schedule is the default)."""
    paths = _paths(tiny, "v1-5-pruned-emaonly.ckpt", "control_v11f1e_sd15_tile.pth", "config_no_scheduler")
    assert missing_weights(paths) == []
    m = load_repair_models(paths)
    for name in m.modules():
        _assert_same_parameters(getattr(m, name), getattr(tiny["models"], name), name)
    sched = m.scheduler.config
    assert (sched.num_train_timesteps, sched.beta_start, sched.beta_end) == (1000, 0.00085, 0.012)
    assert sched.beta_schedule == "scaled_linear" and sched.steps_offset == 1


@pytest.mark.parametrize(
    ("which", "name", "says"),
    [
        ("sd15", "corrupt.safetensors", "Unable to load weights from checkpoint file"),
        ("controlnet", "corrupt.pth", "Unable to load weights from checkpoint file"),
        ("sd15", "no_vae.safetensors", "Failed to load AutoencoderKL"),
        ("sd15", "no_unet_block.safetensors", "lacks some of the model's tensors"),
        ("sd15", "no_clip_layer.safetensors", "lacks 16 text_encoder tensors (e.g. encoder.layers.1."),
        ("sd15", "control_v11f1e_sd15_tile.safetensors", "Failed to load CLIPTextModel"),
        ("controlnet", "no_zero_conv.safetensors", "diffusers cannot convert it (TypeError"),
        ("controlnet", "v1-5-pruned-emaonly.safetensors", "diffusers cannot convert it (TypeError"),
    ],
)
def test_unusable_single_file_is_a_missing_weights_error_naming_it(tiny, which, name, says):
    good = _paths(tiny, "v1-5-pruned-emaonly.safetensors", "control_v11f1e_sd15_tile.safetensors")
    bad = tiny["root"] / name
    paths = WeightPaths(**{**good.describe(), which: str(bad)})
    assert missing_weights(paths) == []  # a file with a weights suffix: found; reading it is the loader's job
    with pytest.raises(MissingWeightsError) as err:
        load_repair_models(paths)
    msg = str(err.value)
    assert f"{which}: {bad}" in msg and says in msg and "\n" not in msg


def test_configs_folder_lacking_files_is_reported_before_loading(tiny, tmp_path):
    paths = _paths(tiny, "v1-5-pruned-emaonly.safetensors", "control_v11f1e_sd15_tile.safetensors")
    cfg = tmp_path / "cfg"
    (cfg / "unet").mkdir(parents=True)
    (cfg / "unet" / "config.json").write_text("{}")
    problems = missing_weights(WeightPaths(**{**paths.describe(), "single_file_config": str(cfg)}))
    assert len(problems) == 2
    assert problems[0].startswith(f"sd15: {paths.sd15} is a single file but {cfg} has no model_index.json / ")
    assert "unet/config.json" not in problems[0] and "text_encoder/config.json" in problems[0]
    assert "controlnet/config.json or config.json" in problems[1]
    assert all("single_file_config" in p for p in problems)
    with pytest.raises(MissingWeightsError, match="has no model_index.json"):
        load_repair_models(WeightPaths(**{**paths.describe(), "single_file_config": str(cfg)}))
