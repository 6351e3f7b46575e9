"""Architecture configs of the repair model: the real SD1.5 + ControlNet-tile sizes and a tiny test size.

The SD1.5 numbers are the published architecture (UNet 320/640/1280/1280, VAE 128/256/512/512, CLIP ViT-L/14
text encoder with 12 layers of width 768); they are used by the benchmark to time the real model with random
weights. The tiny configs keep every structural feature (cross-attention transformer blocks, 8x VAE
downsampling, ControlNet conditioning embedding with 8x downsampling) so that every code path runs in tests.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

# DDIM/DDPM schedule of Stable Diffusion 1.x (scaled-linear betas, 1000 training steps).
SD15_SCHEDULER: dict[str, Any] = {
    "num_train_timesteps": 1000,
    "beta_start": 0.00085,
    "beta_end": 0.012,
    "beta_schedule": "scaled_linear",
    "clip_sample": False,
    "set_alpha_to_one": False,
    "steps_offset": 1,
    "prediction_type": "epsilon",
}


@dataclass(frozen=True)
class RepairArchitecture:
    """Keyword configs for UNet2DConditionModel, ControlNetModel, AutoencoderKL and CLIPTextConfig."""

    unet: dict[str, Any]
    controlnet: dict[str, Any]
    vae: dict[str, Any]
    text_encoder: dict[str, Any]
    scheduler: dict[str, Any] = field(default_factory=lambda: dict(SD15_SCHEDULER))
    tokenizer_max_length: int = 77


def sd15_architecture() -> RepairArchitecture:
    """The full Stable Diffusion 1.5 + ControlNet v1.1 architecture (as in the released configs)."""
    down = ["CrossAttnDownBlock2D", "CrossAttnDownBlock2D", "CrossAttnDownBlock2D", "DownBlock2D"]
    shared = {
        "in_channels": 4,
        "down_block_types": down,
        "block_out_channels": [320, 640, 1280, 1280],
        "layers_per_block": 2,
        "cross_attention_dim": 768,
        "attention_head_dim": 8,
        "norm_num_groups": 32,
    }
    unet = {
        **shared,
        "sample_size": 64,
        "out_channels": 4,
        "up_block_types": ["UpBlock2D", "CrossAttnUpBlock2D", "CrossAttnUpBlock2D", "CrossAttnUpBlock2D"],
    }
    controlnet = {**shared, "conditioning_embedding_out_channels": [16, 32, 96, 256]}
    vae = {
        "in_channels": 3,
        "out_channels": 3,
        "down_block_types": ["DownEncoderBlock2D"] * 4,
        "up_block_types": ["UpDecoderBlock2D"] * 4,
        "block_out_channels": [128, 256, 512, 512],
        "layers_per_block": 2,
        "latent_channels": 4,
        "norm_num_groups": 32,
        "sample_size": 512,
        "scaling_factor": 0.18215,
    }
    text = {
        "vocab_size": 49408,
        "hidden_size": 768,
        "intermediate_size": 3072,
        "num_hidden_layers": 12,
        "num_attention_heads": 12,
        "max_position_embeddings": 77,
        "hidden_act": "quick_gelu",
        "projection_dim": 768,
    }
    return RepairArchitecture(unet, controlnet, vae, text)


def reduced_architecture() -> RepairArchitecture:
    """SD1.5's layout at about 1/4 of its width (for CPU timing runs that must finish in minutes)."""
    full = sd15_architecture()
    unet = {**full.unet, "block_out_channels": [96, 192, 384, 384], "layers_per_block": 1}
    controlnet = {**full.controlnet, "block_out_channels": [96, 192, 384, 384], "layers_per_block": 1}
    vae = {**full.vae, "block_out_channels": [32, 64, 128, 128], "layers_per_block": 1}
    text = {**full.text_encoder, "num_hidden_layers": 4}
    return RepairArchitecture(unet, controlnet, vae, text)


def tiny_architecture(vocab_size: int = 1000) -> RepairArchitecture:
    """A few-hundred-thousand-parameter model with every structural feature of SD1.5 + ControlNet."""
    down = ["CrossAttnDownBlock2D", "DownBlock2D"]
    shared = {
        "in_channels": 4,
        "down_block_types": down,
        "block_out_channels": [16, 32],
        "layers_per_block": 1,
        "cross_attention_dim": 32,
        "attention_head_dim": 4,
        "norm_num_groups": 8,
    }
    unet = {
        **shared,
        "sample_size": 8,
        "out_channels": 4,
        "up_block_types": ["UpBlock2D", "CrossAttnUpBlock2D"],
    }
    controlnet = {**shared, "conditioning_embedding_out_channels": [8, 8, 8, 8]}
    vae = {
        "in_channels": 3,
        "out_channels": 3,
        "down_block_types": ["DownEncoderBlock2D"] * 4,
        "up_block_types": ["UpDecoderBlock2D"] * 4,
        "block_out_channels": [8, 8, 16, 16],
        "layers_per_block": 1,
        "latent_channels": 4,
        "norm_num_groups": 4,
        "sample_size": 64,
        "scaling_factor": 0.18215,
    }
    text = {
        "vocab_size": vocab_size,
        "hidden_size": 32,
        "intermediate_size": 64,
        "num_hidden_layers": 2,
        "num_attention_heads": 4,
        "max_position_embeddings": 77,
        "hidden_act": "quick_gelu",
        "projection_dim": 32,
    }
    return RepairArchitecture(unet, controlnet, vae, text)
