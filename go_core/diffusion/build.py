"""Build randomly initialised repair models from an architecture and save them in the diffusers layout.

Used by the tests (tiny models standing in for SD1.5 / ControlNet-tile / CLIP, which cannot be downloaded
here) and by the benchmark (the full-size architecture with random weights, for timing only).
"""

from __future__ import annotations

import json
from pathlib import Path

from go_core.diffusion.configs import RepairArchitecture
from go_core.diffusion.models import RepairModels
from go_core.seeding import seeded_torch_init


def _byte_symbols() -> list[str]:
    """The 256 printable stand-ins that byte-level BPE (GPT-2 / CLIP) uses for raw bytes."""
    keep = list(range(ord("!"), ord("~") + 1)) + list(range(ord("¡"), ord("¬") + 1))
    keep += list(range(ord("®"), ord("ÿ") + 1))
    symbols, extra = [], 0
    for b in range(256):
        if b in keep:
            symbols.append(chr(b))
        else:
            symbols.append(chr(256 + extra))
            extra += 1
    return symbols


def tiny_tokenizer_files(folder: str | Path, merges: list[str] | None = None) -> Path:
    """Write a small CLIP BPE vocabulary (every byte symbol, with and without ``</w>``) plus a few merges."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    merges = merges or ["p h", "ph o", "o t", "o f</w>", "a</w> p", "x x", "xx y"]
    vocab: dict[str, int] = {}
    for s in _byte_symbols():
        vocab.setdefault(s, len(vocab))
    for s in _byte_symbols():
        vocab.setdefault(s + "</w>", len(vocab))
    for m in merges:
        vocab.setdefault(m.replace(" ", ""), len(vocab))
    for special in ("<|startoftext|>", "<|endoftext|>"):
        vocab.setdefault(special, len(vocab))
    (folder / "vocab.json").write_text(json.dumps(vocab), encoding="utf-8")
    (folder / "merges.txt").write_text("#version: 0.2\n" + "\n".join(merges) + "\n", encoding="utf-8")
    return folder


def build_random_models(
    arch: RepairArchitecture, seed: int = 0, tokenizer_dir: str | Path | None = None
) -> RepairModels:
    """Randomly initialised UNet, ControlNet, VAE and CLIP text encoder (+ a tokenizer) for ``arch``."""
    from diffusers import AutoencoderKL, ControlNetModel, DDIMScheduler, UNet2DConditionModel
    from transformers import CLIPTextConfig, CLIPTextModel, CLIPTokenizer

    with seeded_torch_init(seed):  # the constructors draw their initial weights from torch's global RNG
        unet = UNet2DConditionModel(**arch.unet)
        controlnet = ControlNetModel(**arch.controlnet)
        vae = AutoencoderKL(**arch.vae)
    tokenizer, special = None, {}
    if tokenizer_dir is not None:
        tokenizer = CLIPTokenizer(
            vocab=str(Path(tokenizer_dir) / "vocab.json"), merges=str(Path(tokenizer_dir) / "merges.txt")
        )
        tokenizer.model_max_length = arch.tokenizer_max_length
        special = {
            "eos_token_id": tokenizer.eos_token_id,
            "bos_token_id": tokenizer.bos_token_id,
            "pad_token_id": tokenizer.pad_token_id,
        }
    with seeded_torch_init(seed, "text_encoder"):
        text_encoder = CLIPTextModel(CLIPTextConfig(**arch.text_encoder, **special))
    scheduler = DDIMScheduler(**arch.scheduler)
    return RepairModels(
        unet=unet,
        controlnet=controlnet,
        vae=vae,
        text_encoder=text_encoder,
        tokenizer=tokenizer,
        scheduler=scheduler,
        sources={"built": "random"},
    )


def save_diffusers_layout(models: RepairModels, sd_dir: str | Path, controlnet_dir: str | Path) -> None:
    """Save as a Stable Diffusion diffusers folder (model_index.json + components) and a ControlNet folder."""
    import diffusers

    sd_dir, controlnet_dir = Path(sd_dir), Path(controlnet_dir)
    sd_dir.mkdir(parents=True, exist_ok=True)
    models.unet.save_pretrained(sd_dir / "unet")
    models.vae.save_pretrained(sd_dir / "vae")
    models.text_encoder.save_pretrained(sd_dir / "text_encoder")
    if models.tokenizer is not None:
        models.tokenizer.save_pretrained(sd_dir / "tokenizer")
    models.scheduler.save_pretrained(sd_dir / "scheduler")
    index = {
        "_class_name": "StableDiffusionPipeline",
        "_diffusers_version": diffusers.__version__,
        "unet": ["diffusers", "UNet2DConditionModel"],
        "vae": ["diffusers", "AutoencoderKL"],
        "text_encoder": ["transformers", "CLIPTextModel"],
        "tokenizer": ["transformers", "CLIPTokenizer"],
        "scheduler": ["diffusers", "DDIMScheduler"],
        "safety_checker": [None, None],
        "feature_extractor": [None, None],
        "requires_safety_checker": False,
    }
    (sd_dir / "model_index.json").write_text(json.dumps(index, indent=2), encoding="utf-8")
    models.controlnet.save_pretrained(controlnet_dir)


def write_tiny_weights(root: str | Path, seed: int = 0) -> dict[str, str]:
    """Tiny random SD + ControlNet folders under ``root``; returns the params that point the steps at them."""
    from go_core.diffusion.configs import tiny_architecture

    root = Path(root)
    tok_dir = tiny_tokenizer_files(root / "tokenizer_src")
    models = build_random_models(tiny_architecture(), seed=seed, tokenizer_dir=tok_dir)
    save_diffusers_layout(models, root / "sd15", root / "controlnet_tile")
    return {"sd15_path": str(root / "sd15"), "controlnet_path": str(root / "controlnet_tile")}
