"""Diffusers state dicts → the original CompVis/LDM single-file layout (test helper).

The original Stable Diffusion 1.x checkpoints (``v1-5-pruned-emaonly.safetensors``) hold every component in
one flat state dict: the UNet under ``model.diffusion_model.``, the VAE under ``first_stage_model.`` and the
CLIP text encoder under ``cond_stage_model.transformer.``; ControlNet v1.1 files hold the control net under
``control_model.``. These functions rename a diffusers model's tensors into that layout (the inverse of what
diffusers' single-file loader does), so tests can write such a file from tiny random models and check that
loading it back gives the same tensors.

LDM numbering used below (``n`` = layers per block, ``L`` = number of resolution levels):

* UNet ``input_blocks``: 0 is ``conv_in``; level ``b`` layer ``j`` is ``1 + b*(n+1) + j`` (``.0`` the resnet,
  ``.1`` the transformer), and the downsampler of level ``b`` is the block after its layers (``.0.op``).
* UNet ``output_blocks``: level ``b`` (diffusers ``up_blocks`` order) layer ``j`` is ``b*(n+1) + j``; the
  upsampler sits in the level's last block after the resnet and, when there is one, the transformer.
* ``middle_block``: 0 resnet, 1 transformer, 2 resnet.
* VAE: ``encoder.down.{b}.block.{j}``; the decoder's levels are numbered from the lowest resolution up, so
  diffusers ``decoder.up_blocks.{i}`` is LDM ``decoder.up.{L-1-i}``; the mid attention is a 1x1-conv block
  (``q``/``k``/``v``/``proj_out`` weights of shape ``[C, C, 1, 1]``).
"""

from __future__ import annotations

import re

import torch

UNET_PREFIX = "model.diffusion_model."
CONTROLNET_PREFIX = "control_model."
VAE_PREFIX = "first_stage_model."
CLIP_PREFIX = "cond_stage_model.transformer."

# resnet parameter names: diffusers → LDM (UNet / ControlNet resnets)
_UNET_RESNET = {
    "norm1": "in_layers.0",
    "conv1": "in_layers.2",
    "time_emb_proj": "emb_layers.1",
    "norm2": "out_layers.0",
    "conv2": "out_layers.3",
    "conv_shortcut": "skip_connection",
}
_UNET_TOP = {
    "time_embedding.linear_1": "time_embed.0",
    "time_embedding.linear_2": "time_embed.2",
    "conv_in": "input_blocks.0.0",
    "conv_norm_out": "out.0",
    "conv_out": "out.2",
}
# the VAE's mid attention: diffusers (linear) → LDM (1x1 conv)
_VAE_ATTN = {"group_norm": "norm", "to_q": "q", "to_k": "k", "to_v": "v", "to_out.0": "proj_out"}


def _split(key: str) -> tuple[str, str]:
    """``'a.b.weight'`` → (``'a.b'``, ``'weight'``)."""
    module, _, leaf = key.rpartition(".")
    return module, leaf


def _resnet(rest: str) -> str:
    """Rename a UNet resnet parameter path's first part (``conv1.weight`` → ``in_layers.2.weight``)."""
    head, _, tail = rest.partition(".")
    return f"{_UNET_RESNET[head]}.{tail}"


def _levels(keys: list[str], pattern: str) -> int:
    return 1 + max(int(m.group(1)) for k in keys if (m := re.match(pattern, k)))


def _unet_body_key(key: str, n: int, up_has_attn: set[int]) -> str | None:
    """LDM name of a diffusers UNet/ControlNet key shared by both (None: not a shared key)."""
    for new, old in _UNET_TOP.items():
        if key.startswith(new + "."):
            return old + key[len(new) :]
    if m := re.match(r"down_blocks\.(\d+)\.resnets\.(\d+)\.(.+)", key):
        b, j, rest = int(m.group(1)), int(m.group(2)), m.group(3)
        return f"input_blocks.{1 + b * (n + 1) + j}.0.{_resnet(rest)}"
    if m := re.match(r"down_blocks\.(\d+)\.attentions\.(\d+)\.(.+)", key):
        b, j, rest = int(m.group(1)), int(m.group(2)), m.group(3)
        return f"input_blocks.{1 + b * (n + 1) + j}.1.{rest}"
    if m := re.match(r"down_blocks\.(\d+)\.downsamplers\.0\.conv\.(.+)", key):
        b, leaf = int(m.group(1)), m.group(2)
        return f"input_blocks.{1 + b * (n + 1) + n}.0.op.{leaf}"
    if m := re.match(r"up_blocks\.(\d+)\.resnets\.(\d+)\.(.+)", key):
        b, j, rest = int(m.group(1)), int(m.group(2)), m.group(3)
        return f"output_blocks.{b * (n + 1) + j}.0.{_resnet(rest)}"
    if m := re.match(r"up_blocks\.(\d+)\.attentions\.(\d+)\.(.+)", key):
        b, j, rest = int(m.group(1)), int(m.group(2)), m.group(3)
        return f"output_blocks.{b * (n + 1) + j}.1.{rest}"
    if m := re.match(r"up_blocks\.(\d+)\.upsamplers\.0\.conv\.(.+)", key):
        b, leaf = int(m.group(1)), m.group(2)
        slot = 2 if b in up_has_attn else 1
        return f"output_blocks.{b * (n + 1) + n}.{slot}.conv.{leaf}"
    if m := re.match(r"mid_block\.resnets\.(\d)\.(.+)", key):
        return f"middle_block.{2 * int(m.group(1))}.{_resnet(m.group(2))}"
    if m := re.match(r"mid_block\.attentions\.0\.(.+)", key):
        return f"middle_block.1.{m.group(1)}"
    return None


def _checked(out: dict[str, torch.Tensor], sd: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    if len(out) != len(sd):
        raise AssertionError(f"{len(sd) - len(out)} tensors were mapped onto an already used LDM name")
    return out


def unet_to_ldm(
    sd: dict[str, torch.Tensor], layers_per_block: int, prefix: str = UNET_PREFIX
) -> dict[str, torch.Tensor]:
    """A diffusers ``UNet2DConditionModel`` state dict in the LDM ``model.diffusion_model.*`` layout."""
    keys = list(sd)
    up_has_attn = {int(m.group(1)) for k in keys if (m := re.match(r"up_blocks\.(\d+)\.attentions\.", k))}
    out = {}
    for key, value in sd.items():
        new = _unet_body_key(key, layers_per_block, up_has_attn)
        if new is None:
            raise KeyError(f"no LDM name for UNet key {key}")
        out[prefix + new] = value
    return _checked(out, sd)


def controlnet_to_ldm(
    sd: dict[str, torch.Tensor], layers_per_block: int, prefix: str = CONTROLNET_PREFIX
) -> dict[str, torch.Tensor]:
    """A diffusers ``ControlNetModel`` state dict in the ControlNet v1.x ``control_model.*`` layout.

    The hint encoder is one ``Sequential`` of convolutions with a SiLU after each, so diffusers'
    ``controlnet_cond_embedding.conv_in`` / ``blocks.k`` / ``conv_out`` are its even entries 0 / 2k+2 / last.
    """
    n_hint = _levels(list(sd), r"controlnet_cond_embedding\.blocks\.(\d+)\.")
    out = {}
    for key, value in sd.items():
        if m := re.match(r"controlnet_cond_embedding\.(conv_in|conv_out|blocks\.(\d+))\.(weight|bias)$", key):
            index = {"conv_in": 0, "conv_out": 2 * (n_hint + 1)}.get(m.group(1))
            index = 2 * (int(m.group(2)) + 1) if index is None else index
            new = f"input_hint_block.{index}.{m.group(3)}"
        elif m := re.match(r"controlnet_down_blocks\.(\d+)\.(weight|bias)$", key):
            new = f"zero_convs.{m.group(1)}.0.{m.group(2)}"
        elif m := re.match(r"controlnet_mid_block\.(weight|bias)$", key):
            new = f"middle_block_out.0.{m.group(1)}"
        else:
            new = _unet_body_key(key, layers_per_block, up_has_attn=set())
        if new is None:
            raise KeyError(f"no LDM name for ControlNet key {key}")
        out[prefix + new] = value
    return _checked(out, sd)


def _vae_resnet(rest: str) -> str:
    return rest.replace("conv_shortcut.", "nin_shortcut.", 1)


def vae_to_ldm(sd: dict[str, torch.Tensor], prefix: str = VAE_PREFIX) -> dict[str, torch.Tensor]:
    """A diffusers ``AutoencoderKL`` state dict in the LDM ``first_stage_model.*`` layout."""
    n_up = _levels(list(sd), r"decoder\.up_blocks\.(\d+)\.")
    out = {}
    for key, value in sd.items():
        new = None
        if m := re.match(r"(encoder|decoder)\.conv_norm_out\.(.+)", key):
            new = f"{m.group(1)}.norm_out.{m.group(2)}"
        elif re.match(r"(encoder|decoder)\.(conv_in|conv_out)\.|(post_)?quant_conv\.", key):
            new = key
        elif m := re.match(r"encoder\.down_blocks\.(\d+)\.resnets\.(\d+)\.(.+)", key):
            new = f"encoder.down.{m.group(1)}.block.{m.group(2)}.{_vae_resnet(m.group(3))}"
        elif m := re.match(r"encoder\.down_blocks\.(\d+)\.downsamplers\.0\.conv\.(.+)", key):
            new = f"encoder.down.{m.group(1)}.downsample.conv.{m.group(2)}"
        elif m := re.match(r"decoder\.up_blocks\.(\d+)\.resnets\.(\d+)\.(.+)", key):
            level = n_up - 1 - int(m.group(1))
            new = f"decoder.up.{level}.block.{m.group(2)}.{_vae_resnet(m.group(3))}"
        elif m := re.match(r"decoder\.up_blocks\.(\d+)\.upsamplers\.0\.conv\.(.+)", key):
            new = f"decoder.up.{n_up - 1 - int(m.group(1))}.upsample.conv.{m.group(2)}"
        elif m := re.match(r"(encoder|decoder)\.mid_block\.resnets\.(\d)\.(.+)", key):
            new = f"{m.group(1)}.mid.block_{int(m.group(2)) + 1}.{_vae_resnet(m.group(3))}"
        elif m := re.match(r"(encoder|decoder)\.mid_block\.attentions\.0\.(.+)", key):
            module, leaf = _split(m.group(2))
            new = f"{m.group(1)}.mid.attn_1.{_VAE_ATTN[module]}.{leaf}"
            if leaf == "weight" and module != "group_norm":
                value = value[:, :, None, None]  # linear [C, C] → 1x1 conv [C, C, 1, 1]
        if new is None:
            raise KeyError(f"no LDM name for VAE key {key}")
        out[prefix + new] = value
    return _checked(out, sd)


def clip_to_ldm(sd: dict[str, torch.Tensor], prefix: str = CLIP_PREFIX) -> dict[str, torch.Tensor]:
    """A transformers ``CLIPTextModel`` state dict in the SD1.x ``cond_stage_model.transformer.*`` layout.

    The original files hold the text tower as ``transformer.text_model.*`` (transformers >= 5.6 dropped the
    ``text_model.`` level from ``CLIPTextModel`` itself), plus the ``position_ids`` buffer.
    """
    out = {}
    for key, value in sd.items():
        out[prefix + (key if key.startswith("text_model.") else "text_model." + key)] = value
    n_pos = out[prefix + "text_model.embeddings.position_embedding.weight"].shape[0]
    out[prefix + "text_model.embeddings.position_ids"] = torch.arange(n_pos)[None]
    return out


def sd15_single_file(unet, vae, text_encoder) -> dict[str, torch.Tensor]:
    """The tensors of an original SD1.x checkpoint (plus two of the DDPM schedule buffers it also carries)."""
    sd = {
        **unet_to_ldm(unet.state_dict(), unet.config.layers_per_block),
        **vae_to_ldm(vae.state_dict()),
        **clip_to_ldm(text_encoder.state_dict()),
    }
    betas = torch.linspace(0.00085**0.5, 0.012**0.5, 1000, dtype=torch.float64) ** 2
    sd["betas"] = betas.float()
    sd["alphas_cumprod"] = torch.cumprod(1 - betas, 0).float()
    return {k: v.detach().clone().contiguous() for k, v in sd.items()}


def controlnet_single_file(controlnet) -> dict[str, torch.Tensor]:
    """The tensors of an original ControlNet v1.1 file."""
    sd = controlnet_to_ldm(controlnet.state_dict(), controlnet.config.layers_per_block)
    return {k: v.detach().clone().contiguous() for k, v in sd.items()}
