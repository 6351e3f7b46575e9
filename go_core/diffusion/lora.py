"""LoRA on the repair model (peft): the UNet's and the ControlNet's transformer blocks and the CLIP text
encoder's attention. Base weights stay frozen and bit-identical; only the LoRA tensors train and are saved."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import torch

from go_core.diffusion.models import RepairModels
from go_core.seeding import seeded_torch_init

ADAPTER = "repair"
# Every linear layer of a BasicTransformerBlock: self- and cross-attention projections and the feed-forward.
TRANSFORMER_BLOCK_TARGETS = (
    r".*transformer_blocks\.\d+\.(attn1|attn2)\.(to_q|to_k|to_v|to_out\.0)"
    r"|.*transformer_blocks\.\d+\.ff\.net\.(0\.proj|2)"
)
TEXT_ATTENTION_TARGETS = r".*self_attn\.(q_proj|k_proj|v_proj|out_proj)"
PARTS = ("unet", "controlnet", "text_encoder")


@dataclass(frozen=True)
class LoraSpec:
    """Rank/alpha and which parts of the model get LoRA (paper: rank 64 on all three)."""

    rank: int
    alpha: float
    unet: bool
    controlnet: bool
    text_encoder: bool

    def parts(self) -> list[str]:
        return [p for p in PARTS if getattr(self, p)]


def _config(spec: LoraSpec, targets: str):
    from peft import LoraConfig

    return LoraConfig(
        r=spec.rank, lora_alpha=spec.alpha, lora_dropout=0.0, target_modules=targets, init_lora_weights=True
    )


def add_lora(models: RepairModels, spec: LoraSpec, seed: int = 0) -> dict[str, int]:
    """Freeze every base weight and inject LoRA adapters; returns the number of LoRA parameters per part.

    LoRA's B matrices start at zero, so the model's outputs are unchanged until training moves them; the A
    matrices are drawn from ``seed`` (the global torch RNG is left as it was).
    """
    with seeded_torch_init(int(seed), "lora"):
        return _inject(models, spec)


def _inject(models: RepairModels, spec: LoraSpec) -> dict[str, int]:
    from peft import inject_adapter_in_model

    counts: dict[str, int] = {}
    for name in PARTS:
        module = getattr(models, name)
        module.requires_grad_(False)
        if not getattr(spec, name):
            continue
        targets = TEXT_ATTENTION_TARGETS if name == "text_encoder" else TRANSFORMER_BLOCK_TARGETS
        inject_adapter_in_model(_config(spec, targets), module, adapter_name=ADAPTER)
        n = 0
        for pname, p in module.named_parameters():
            is_lora = "lora_" in pname
            p.requires_grad_(is_lora)
            if is_lora:
                p.data = p.data.float()  # LoRA weights train in float32 even when the base is fp16/bf16
                n += p.numel()
        counts[name] = n
    models.vae.requires_grad_(False)
    return counts


def lora_parameters(models: RepairModels) -> list[torch.nn.Parameter]:
    """The trainable LoRA tensors, in a fixed order (for the optimiser and its checkpoints)."""
    out = []
    for name in PARTS:
        out += [p for pname, p in getattr(models, name).named_parameters() if "lora_" in pname]
    return out


def lora_state_dict(models: RepairModels, spec: LoraSpec) -> dict[str, torch.Tensor]:
    """Only the LoRA tensors, keys prefixed by the part (``unet.``, ``controlnet.``, ``text_encoder.``)."""
    from peft import get_peft_model_state_dict

    out: dict[str, torch.Tensor] = {}
    for name in spec.parts():
        sd = get_peft_model_state_dict(getattr(models, name), adapter_name=ADAPTER)
        out.update({f"{name}.{k}": v.detach().cpu().float().contiguous() for k, v in sd.items()})
    return out


def load_lora_state_dict(models: RepairModels, spec: LoraSpec, state: dict[str, torch.Tensor]) -> None:
    """Put saved LoRA tensors back into a model that went through ``add_lora`` with the same spec."""
    from peft import set_peft_model_state_dict

    for name in spec.parts():
        prefix = f"{name}."
        part = {k[len(prefix) :]: v for k, v in state.items() if k.startswith(prefix)}
        if not part:
            raise ValueError(f"the LoRA weights hold nothing for {name}")
        result = set_peft_model_state_dict(getattr(models, name), part, adapter_name=ADAPTER)
        unexpected = getattr(result, "unexpected_keys", [])
        if unexpected:
            raise ValueError(f"LoRA weights for {name} do not fit the model: {unexpected[:3]}")


def save_lora(
    path: str | Path, models: RepairModels, spec: LoraSpec, extra: dict[str, str] | None = None
) -> Path:
    """Write the LoRA tensors as safetensors (atomically), with the spec in the metadata."""
    from go_core.io.safetensors_file import write_safetensors

    meta = {
        "rank": str(spec.rank),
        "alpha": str(spec.alpha),
        "parts": ",".join(spec.parts()),
        **(extra or {}),
    }
    state = lora_state_dict(models, spec)
    return write_safetensors(path, state, meta)


def read_lora(path: str | Path) -> tuple[LoraSpec, dict[str, torch.Tensor]]:
    """The spec and tensors saved by ``save_lora``."""
    from safetensors import safe_open

    with safe_open(str(path), framework="pt") as f:
        meta = f.metadata() or {}
        state = {k: f.get_tensor(k) for k in f.keys()}
    parts = set(meta.get("parts", ",".join(PARTS)).split(","))
    spec = LoraSpec(
        rank=int(meta.get("rank", 64)),
        alpha=float(meta.get("alpha", 64.0)),
        unet="unet" in parts,
        controlnet="controlnet" in parts,
        text_encoder="text_encoder" in parts,
    )
    return spec, state
