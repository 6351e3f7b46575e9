"""LoRA on the repair model: frozen bit-identical base, only LoRA trains, loss falls, save/load roundtrip."""

from __future__ import annotations

import pytest
import torch

from go_core.diffusion.lora import (
    LoraSpec,
    add_lora,
    load_lora_state_dict,
    lora_parameters,
    read_lora,
    save_lora,
)
from go_core.diffusion.models import WeightPaths, load_repair_models
from go_core.diffusion.sampler import RepairDiffusion
from tests._tiny_repair import tiny_weights

ALL_PARTS = {"unet": True, "controlnet": True, "text_encoder": True}  # LoRA on every part (the paper's)


@pytest.fixture(scope="module")
def weights(tmp_path_factory):
    return tiny_weights(tmp_path_factory.mktemp("tiny_repair"))


pytestmark = pytest.mark.usefixtures("single_thread")  # small tensors: one thread is faster


def _base_state(models) -> dict[str, torch.Tensor]:
    """Every non-LoRA tensor, keyed by its name without peft's ``base_layer`` wrapper."""
    out = {}
    for part, module in models.modules().items():
        for k, v in module.state_dict().items():
            if "lora_" not in k:
                out[f"{part}.{k.replace('.base_layer', '')}"] = v.detach().clone()
    return out


def _pair():
    g = torch.Generator().manual_seed(3)
    clean = torch.rand(1, 3, 64, 64, generator=g)
    return (clean + 0.3 * torch.randn(1, 3, 64, 64, generator=g)).clamp(0, 1), clean


def test_lora_trains_only_lora_and_keeps_base_bit_identical(weights):
    m = load_repair_models(WeightPaths.resolve(weights, env={}))
    before = _base_state(m)
    spec = LoraSpec(rank=8, alpha=8, **ALL_PARTS)
    counts = add_lora(m, spec)
    assert set(counts) == {"unet", "controlnet", "text_encoder"} and all(n > 0 for n in counts.values())
    trainable = [
        (part, n) for part, mod in m.modules().items() for n, p in mod.named_parameters() if p.requires_grad
    ]
    assert trainable and all("lora_" in n for _, n in trainable)
    assert {p for p, _ in trainable} == {"unet", "controlnet", "text_encoder"}  # never the VAE
    names = [n for _, n in trainable]
    assert any("transformer_blocks" in n and "attn2.to_k" in n for n in names)
    assert any("self_attn.q_proj" in n for n in names)
    params = lora_parameters(m)
    assert sum(p.numel() for p in params) == sum(counts.values())

    d = RepairDiffusion(m)
    deg, clean = _pair()
    opt = torch.optim.AdamW(params, lr=1e-3, betas=(0.9, 0.999))
    start = [p.detach().clone() for p in params]
    for _ in range(3):
        loss = d.tuning_loss(deg, clean, torch.Generator().manual_seed(5))
        opt.zero_grad()
        loss.backward()
        opt.step()
    after = _base_state(m)
    assert before.keys() == after.keys()
    assert all(torch.equal(before[k], after[k]) for k in before)  # bit-identical base weights
    assert any(not torch.equal(a, p) for a, p in zip(start, params, strict=True))


def test_tuning_loss_falls_on_tiny_overfit_case(weights):
    m = load_repair_models(WeightPaths.resolve(weights, env={}))
    add_lora(m, LoraSpec(rank=8, alpha=8, **ALL_PARTS))
    d = RepairDiffusion(m)
    deg, clean = _pair()
    opt = torch.optim.AdamW(lora_parameters(m), lr=1e-2)
    losses = []
    for _ in range(25):
        loss = d.tuning_loss(deg, clean, torch.Generator().manual_seed(7))  # same t and ε every step
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
    assert losses[-1] < 0.5 * losses[0], losses


def test_lora_save_load_roundtrip_reproduces_outputs(weights, tmp_path):
    spec = LoraSpec(rank=4, alpha=8, **ALL_PARTS)
    m = load_repair_models(WeightPaths.resolve(weights, env={}))
    add_lora(m, spec)
    with torch.no_grad():
        for p in lora_parameters(m):
            p.add_(0.05 * torch.randn(p.shape, generator=torch.Generator().manual_seed(p.numel())))
    path = save_lora(tmp_path / "lora.safetensors", m, spec)
    spec2, state = read_lora(path)
    assert spec2 == spec and all(k.split(".")[0] in {"unet", "controlnet", "text_encoder"} for k in state)
    assert all("lora_" in k for k in state)  # only LoRA tensors are saved
    m2 = load_repair_models(WeightPaths.resolve(weights, env={}))
    add_lora(m2, spec2)
    load_lora_state_dict(m2, spec2, state)
    deg, clean = _pair()
    with torch.no_grad():
        a = RepairDiffusion(m).tuning_loss(deg, clean, torch.Generator().manual_seed(1))
        b = RepairDiffusion(m2).tuning_loss(deg, clean, torch.Generator().manual_seed(1))
        base = load_repair_models(WeightPaths.resolve(weights, env={}))
        c = RepairDiffusion(base).tuning_loss(deg, clean, torch.Generator().manual_seed(1))
    assert torch.equal(a, b) and not torch.equal(a, c)


def test_precision_choice():
    from go_core.diffusion.models import precision_dtypes

    assert precision_dtypes("cpu", "bf16") == (torch.float32, None)  # CPU always runs float32
    assert precision_dtypes("cuda", "auto") == (torch.bfloat16, torch.bfloat16)
    assert precision_dtypes("cuda:0", "fp16") == (torch.float16, torch.float16)
    assert precision_dtypes("cuda", "fp32") == (torch.float32, None)
    with pytest.raises(ValueError):
        precision_dtypes("cuda", "int8")


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
@pytest.mark.parametrize("precision", ["bf16", "fp16"])
def test_half_precision_lora_step_on_cuda(weights, precision):
    from go_core.diffusion.models import precision_dtypes

    dtype, autocast = precision_dtypes("cuda", precision)
    m = load_repair_models(WeightPaths.resolve(weights, env={}), device="cuda", dtype=dtype)
    add_lora(m, LoraSpec(rank=4, alpha=4, **ALL_PARTS))
    for module in m.modules().values():
        module.to("cuda")
    assert next(m.unet.parameters()).dtype == dtype
    assert all(p.dtype == torch.float32 for p in lora_parameters(m))
    d = RepairDiffusion(m, device="cuda", autocast_dtype=autocast)
    deg, clean = _pair()
    opt = torch.optim.AdamW(lora_parameters(m), lr=1e-3)
    loss = d.tuning_loss(deg.cuda(), clean.cuda(), torch.Generator().manual_seed(0))
    loss.backward()
    opt.step()
    assert torch.isfinite(loss)
    out = d.repair(deg.cuda(), 0.3, torch.Generator().manual_seed(1), 50, 1.0)
    assert out.images.shape == (1, 3, 64, 64) and torch.isfinite(out.images).all()
