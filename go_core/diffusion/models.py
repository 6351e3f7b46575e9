"""Loading the repair model (SD 1.5 + ControlNet v1.1 tile + CLIP text encoder) from local paths.

Nothing is downloaded: every weight comes from a path given in the step params or the environment.
Accepted forms:

* a diffusers folder: SD1.5 as a pipeline folder (``model_index.json``, ``unet/``, ``vae/``,
  ``text_encoder/``, ``tokenizer/``, ``scheduler/``), the ControlNet as a model folder (``config.json``
  + weights);
* an original single file (``.ckpt`` / ``.safetensors`` / ``.pth``) loaded through diffusers' single-file
  loaders. Offline, those loaders need the diffusers *configs* of the model: give a folder in the diffusers
  layout holding the config/tokenizer files (weights not needed) as ``single_file_config``.
* ``clip_path`` (optional): a transformers CLIPTextModel folder (CLIP ViT-L/14 text tower) that replaces the
  SD folder's ``text_encoder``; a ``tokenizer/`` inside it (or the folder itself) replaces the tokenizer.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from go_core.errors import MissingWeightsError, first_line

ENV_SD15 = "GO_SD15_PATH"
ENV_CONTROLNET = "GO_CONTROLNET_TILE_PATH"
ENV_CLIP = "GO_CLIP_PATH"
ENV_SINGLE_FILE_CONFIG = "GO_SD15_CONFIG"

SINGLE_FILE_SUFFIXES = (".ckpt", ".safetensors", ".pth", ".pt", ".bin")

HOW_TO_GET = {
    "sd15": (
        "Stable Diffusion 1.5: download the diffusers folder 'stable-diffusion-v1-5/stable-diffusion-v1-5' "
        "(or the single file v1-5-pruned-emaonly.safetensors) on a machine with internet, then "
        f"--set weights.sd15_path=... or ${ENV_SD15}"
    ),
    "controlnet": (
        "ControlNet v1.1 tile: download 'lllyasviel/control_v11f1e_sd15_tile' (diffusers folder, or the "
        "single file control_v11f1e_sd15_tile.pth), then "
        f"--set weights.controlnet_path=... or ${ENV_CONTROLNET}"
    ),
    "clip": (
        "CLIP ViT-L/14 text encoder: the SD1.5 folder's text_encoder/ is used; to override, download "
        f"'openai/clip-vit-large-patch14' then --set weights.clip_path=... or ${ENV_CLIP}"
    ),
    "config": (
        "single-file weights need the diffusers configs offline: give a diffusers-layout folder with the "
        f"config.json/tokenizer files as --set weights.single_file_config=... or ${ENV_SINGLE_FILE_CONFIG}"
    ),
}


@dataclass
class RepairModels:
    """The pieces of the repair model. ``tokenizer`` may be None only for timing runs without text input."""

    unet: Any
    controlnet: Any
    vae: Any
    text_encoder: Any
    tokenizer: Any
    scheduler: Any  # a diffusers DDIMScheduler (its add_noise / alphas_cumprod also serve training)
    sources: dict[str, str] = field(default_factory=dict)

    def modules(self) -> dict[str, torch.nn.Module]:
        return {
            "unet": self.unet,
            "controlnet": self.controlnet,
            "vae": self.vae,
            "text_encoder": self.text_encoder,
        }

    def to(self, device: str | torch.device, dtype: torch.dtype | None = None) -> RepairModels:
        for m in self.modules().values():
            m.to(device)
            if dtype is not None and next(m.parameters()).dtype != dtype:
                m.to(dtype)
        return self


@dataclass(frozen=True)
class WeightPaths:
    """Where the weights live (empty string: not given)."""

    sd15: str = ""
    controlnet: str = ""
    clip: str = ""
    single_file_config: str = ""

    @staticmethod
    def resolve(params: dict, env: dict[str, str] | None = None) -> WeightPaths:
        """Params win over the environment (``GO_SD15_PATH``, ``GO_CONTROLNET_TILE_PATH``, ...)."""
        env = dict(os.environ) if env is None else env
        return WeightPaths(
            sd15=str(params.get("sd15_path") or env.get(ENV_SD15, "")),
            controlnet=str(params.get("controlnet_path") or env.get(ENV_CONTROLNET, "")),
            clip=str(params.get("clip_path") or env.get(ENV_CLIP, "")),
            single_file_config=str(params.get("single_file_config") or env.get(ENV_SINGLE_FILE_CONFIG, "")),
        )

    def describe(self) -> dict[str, str]:
        return {
            "sd15": self.sd15,
            "controlnet": self.controlnet,
            "clip": self.clip,
            "single_file_config": self.single_file_config,
        }


def precision_dtypes(device: str, precision: str) -> tuple[torch.dtype, torch.dtype | None]:
    """(base weight dtype, autocast dtype) for a device and a precision name.

    CPU: always float32 (no autocast). CUDA: "auto"/"bf16" → bfloat16 weights and autocast, "fp16" → float16,
    "fp32" → float32 without autocast. LoRA tensors are kept in float32 in every case.
    """
    if not str(device).startswith("cuda") or precision == "fp32":
        return torch.float32, None
    dtype = {"auto": torch.bfloat16, "bf16": torch.bfloat16, "fp16": torch.float16}.get(precision)
    if dtype is None:
        raise ValueError(f"precision must be auto, bf16, fp16 or fp32, got {precision!r}")
    return dtype, dtype


def _is_single_file(path: Path) -> bool:
    return path.is_file() and path.suffix.lower() in SINGLE_FILE_SUFFIXES


# What diffusers' single-file loaders read from the configs folder (the scheduler config is optional).
_SINGLE_FILE_CONFIGS = {
    "sd15": (
        ("model_index.json",),
        ("unet/config.json",),
        ("vae/config.json",),
        ("text_encoder/config.json",),
        ("tokenizer/vocab.json", "tokenizer/tokenizer.json"),
    ),
    "controlnet": (("controlnet/config.json", "config.json"),),
}


def _missing_configs(kind: str, cfg: Path) -> list[str]:
    """The config files (any one of each group) that ``cfg`` lacks for loading a ``kind`` single file."""
    groups = _SINGLE_FILE_CONFIGS[kind]
    return [" or ".join(g) for g in groups if not any((cfg / f).is_file() for f in g)]


def missing_weights(paths: WeightPaths, need_controlnet: bool = True) -> list[str]:
    """Human-readable problems with ``paths`` (empty list: everything needed is present)."""
    problems: list[str] = []

    def check(kind: str, value: str, folder_marker: str) -> None:
        if not value:
            problems.append(f"{kind} weights not given. {HOW_TO_GET[kind]}")
            return
        p = Path(value).expanduser()
        if _is_single_file(p):
            if not paths.single_file_config:
                problems.append(f"{kind}: {p} is a single file. {HOW_TO_GET['config']}")
                return
            lacking = _missing_configs(kind, Path(paths.single_file_config).expanduser())
            if lacking:
                problems.append(
                    f"{kind}: {p} is a single file but {paths.single_file_config} has no "
                    f"{' / '.join(lacking)}. {HOW_TO_GET['config']}"
                )
            return
        if not p.is_dir() or not (p / folder_marker).is_file():
            problems.append(
                f"{kind}: {p} is not a diffusers folder (no {folder_marker}) nor a single weights "
                f"file. {HOW_TO_GET[kind]}"
            )

    check("sd15", paths.sd15, "model_index.json")
    if need_controlnet:
        check("controlnet", paths.controlnet, "config.json")
    if paths.clip and not (Path(paths.clip).expanduser() / "config.json").is_file():
        problems.append(f"clip: {paths.clip} has no config.json. {HOW_TO_GET['clip']}")
    return problems


def require_weights(paths: WeightPaths, need_controlnet: bool = True) -> None:
    """Raise one MissingWeightsError listing everything missing and how to obtain it."""
    problems = missing_weights(paths, need_controlnet)
    if problems:
        raise MissingWeightsError("repair model weights missing: " + " | ".join(problems))


def _from_single_file(kind: str, cls: Any, path: Path, **kwargs: Any) -> Any:
    """``cls.from_single_file(path, ...)``; an unreadable file or one without the expected tensors raises
    ValueError starting ``"<kind>: <path>"``.

    diffusers reports a component absent from the file with SingleFileComponentError, a file of another model
    with KeyError/TypeError from its converters, and leaves the tensors a partial file lacks on the meta
    device (where ``.to()`` fails).
    """
    from diffusers.loaders.single_file_utils import SingleFileComponentError

    try:
        loaded = cls.from_single_file(str(path), local_files_only=True, **kwargs)
    except (OSError, ValueError, SingleFileComponentError) as exc:  # unreadable, or a component not in it
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        raise ValueError(f"{kind}: {path}: {first}") from exc
    except (KeyError, TypeError, AttributeError, IndexError) as exc:
        what = f"{type(exc).__name__}: {exc}"
        raise ValueError(f"{kind}: {path}: diffusers cannot convert it ({what})") from exc
    except NotImplementedError as exc:  # "Cannot copy out of meta tensor": the file lacks some tensors
        raise ValueError(f"{kind}: {path} lacks some of the model's tensors ({type(exc).__name__})") from exc
    modules = {kind: loaded} if isinstance(loaded, torch.nn.Module) else loaded.components
    for name, module in modules.items():
        if isinstance(module, torch.nn.Module):
            absent = [n for n, t in module.named_parameters() if t.is_meta]
            if absent:
                raise ValueError(f"{kind}: {path} lacks {len(absent)} {name} tensors (e.g. {absent[0]})")
    return loaded


def _load_sd_components(paths: WeightPaths, dtype: torch.dtype) -> dict[str, Any]:
    from diffusers import AutoencoderKL, DDIMScheduler, UNet2DConditionModel
    from transformers import CLIPTextModel, CLIPTokenizer

    sd = Path(paths.sd15).expanduser()
    cfg = Path(paths.single_file_config).expanduser()
    single = _is_single_file(sd)
    sched_dir = (cfg if single else sd) / "scheduler"
    if (sched_dir / "scheduler_config.json").is_file():
        scheduler = DDIMScheduler.from_pretrained(sched_dir, local_files_only=True)
    else:
        from go_core.diffusion.configs import SD15_SCHEDULER

        scheduler = DDIMScheduler(**SD15_SCHEDULER)
    if single:
        from diffusers import StableDiffusionPipeline

        pipe = _from_single_file(
            "sd15",
            StableDiffusionPipeline,
            sd,
            config=str(cfg),
            torch_dtype=dtype,
            scheduler=scheduler,  # so that the configs folder needs no scheduler/
            safety_checker=None,
            feature_extractor=None,  # listed in SD1.5's model_index.json, not needed, often not downloaded
            requires_safety_checker=False,
        )
        parts = {
            "unet": pipe.unet,
            "vae": pipe.vae,
            "text_encoder": pipe.text_encoder,
            "tokenizer": pipe.tokenizer,
        }
    else:
        parts = {
            "unet": UNet2DConditionModel.from_pretrained(
                sd, subfolder="unet", torch_dtype=dtype, local_files_only=True
            ),
            "vae": AutoencoderKL.from_pretrained(
                sd, subfolder="vae", torch_dtype=dtype, local_files_only=True
            ),
            "text_encoder": CLIPTextModel.from_pretrained(
                sd, subfolder="text_encoder", dtype=dtype, local_files_only=True
            ),
            "tokenizer": CLIPTokenizer.from_pretrained(sd, subfolder="tokenizer", local_files_only=True),
        }
    parts["scheduler"] = scheduler
    if paths.clip:
        clip = Path(paths.clip).expanduser()
        parts["text_encoder"] = CLIPTextModel.from_pretrained(clip, dtype=dtype, local_files_only=True)
        tok = clip / "tokenizer" if (clip / "tokenizer").is_dir() else clip
        if (tok / "vocab.json").is_file() or (tok / "tokenizer.json").is_file():
            parts["tokenizer"] = CLIPTokenizer.from_pretrained(tok, local_files_only=True)
    return parts


def _load_controlnet(paths: WeightPaths, dtype: torch.dtype, unet: Any) -> Any:
    from diffusers import ControlNetModel

    cn = Path(paths.controlnet).expanduser()
    if _is_single_file(cn):
        cfg = Path(paths.single_file_config).expanduser()
        cfg = cfg / "controlnet" if (cfg / "controlnet" / "config.json").is_file() else cfg
        return _from_single_file("controlnet", ControlNetModel, cn, config=str(cfg), torch_dtype=dtype)
    return ControlNetModel.from_pretrained(cn, torch_dtype=dtype, local_files_only=True)


def load_repair_models(
    paths: WeightPaths, device: str = "cpu", dtype: torch.dtype = torch.float32
) -> RepairModels:
    """Load every piece from local paths (raises MissingWeightsError first when something is missing).

    All base weights are frozen (``requires_grad=False``) and in eval mode; LoRA adds the trainable part.
    """
    require_weights(paths)
    try:
        parts = _load_sd_components(paths, dtype)
        cn = _load_controlnet(paths, dtype, parts["unet"])
    except (OSError, ValueError) as exc:  # unreadable / incompatible files: still a weights problem
        raise MissingWeightsError(
            f"could not load the repair model from {paths.describe()}: {first_line(exc)}"
        ) from exc
    models = RepairModels(controlnet=cn, sources=paths.describe(), **parts)
    for m in models.modules().values():
        m.requires_grad_(False)
        m.eval()
    return models.to(device, dtype)
