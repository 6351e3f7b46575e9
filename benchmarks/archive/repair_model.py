"""Time the repair model: one LoRA tuning step and one repair refresh, and extrapolate the repair stages.

Random weights (timing only), architectures from ``go_core.diffusion.configs`` written in code:
* ``--size full``: the real SD1.5 + ControlNet v1.1 + CLIP ViT-L/14 text encoder sizes (default on CUDA);
* ``--size reduced``: the same layout at ~1/4 width (default on CPU, where the full model takes minutes per
  step); ``--size tiny``: the test model. The printed JSON says which one ran; only ``full`` on CUDA at
  512 px is comparable with the paper.

Measured: one LoRA step (rank 64 on UNet/ControlNet transformer blocks + CLIP attention, batch 1, forward +
backward + AdamW) and one repair of one view (VAE encode, ⌊50·t⌋ DDIM steps of UNet + ControlNet at the mean
strength of t ~ U(0.1, 1.0), decode); one refresh = ``views_per_refresh`` (8 = 2 per arc × 4 arcs) repairs.
Extrapolated at paper settings: LoRA 1800 steps; repair 2800/200 = 14 refreshes (+ ``--gs-iter-ms`` per
Gaussian iteration × 4000 if given; the rasteriser is timed by benchmarks/rasterizer.py).
Paper (RTX 3090): about 15 min of repair-model tuning and 14 min of Gaussian repair.

    python benchmarks/archive/repair_model.py [--device cuda] [--size full] [--resolution 512] \
        [--out result.json]
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
from pathlib import Path

import torch
from _machine import cpu_name  # benchmarks/ is on sys.path when run as a script


def _sync(device: str) -> None:
    if device.startswith("cuda"):
        torch.cuda.synchronize()


def _timed(fn, device: str, repeat: int) -> list[float]:
    out = []
    for _ in range(repeat):
        _sync(device)
        t = time.perf_counter()
        fn()
        _sync(device)
        out.append(time.perf_counter() - t)
    return out


def main(argv: list[str] | None = None) -> int:
    from go_core.diffusion.build import build_random_models, tiny_tokenizer_files
    from go_core.diffusion.configs import reduced_architecture, sd15_architecture, tiny_architecture
    from go_core.diffusion.lora import LoraSpec, add_lora, lora_parameters
    from go_core.diffusion.models import precision_dtypes
    from go_core.diffusion.sampler import RepairDiffusion
    from go_core.repair.settings import RepairSettings

    cuda = torch.cuda.is_available()
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cuda" if cuda else "cpu")
    ap.add_argument("--size", choices=["full", "reduced", "tiny"], default="full" if cuda else "reduced")
    ap.add_argument("--resolution", type=int, default=512 if cuda else 256)
    ap.add_argument("--precision", default="auto", help="CUDA: auto/bf16 | fp16 | fp32 (CPU: fp32)")
    ap.add_argument("--rank", type=int, default=64)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--views-per-refresh", type=int, default=8)
    ap.add_argument("--lora-steps", type=int, default=1800)
    ap.add_argument("--refreshes", type=int, default=14)
    ap.add_argument("--gs-iterations", type=int, default=4000)
    ap.add_argument(
        "--gs-iter-ms", type=float, default=None, help="measured ms per Gaussian repair iteration"
    )
    ap.add_argument("--threads", type=int, default=0, help="torch CPU threads (0: torch default)")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    if args.resolution % 64:
        ap.error("--resolution must be a multiple of 64")

    arch = {"full": sd15_architecture, "reduced": reduced_architecture, "tiny": tiny_architecture}[
        args.size
    ]()
    weight_dtype, autocast_dtype = precision_dtypes(args.device, args.precision)
    with tempfile.TemporaryDirectory() as tmp:
        tok = tiny_tokenizer_files(Path(tmp) / "tok")
        t0 = time.perf_counter()
        models = build_random_models(arch, seed=0, tokenizer_dir=tok)
        build_s = time.perf_counter() - t0
    models.to(args.device, weight_dtype)
    counts = add_lora(
        models,
        LoraSpec(rank=args.rank, alpha=float(args.rank), unet=True, controlnet=True, text_encoder=True),
    )
    for m in models.modules().values():
        m.to(args.device)
    diffusion = RepairDiffusion(models, device=args.device, autocast_dtype=autocast_dtype)
    opt = torch.optim.AdamW(lora_parameters(models), lr=1e-3, betas=(0.9, 0.999))
    gen = torch.Generator().manual_seed(0)
    res = args.resolution
    deg, clean = torch.rand(1, 3, res, res, generator=gen), torch.rand(1, 3, res, res, generator=gen)

    def lora_step() -> None:
        loss = diffusion.tuning_loss(deg.to(args.device), clean.to(args.device), gen)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()

    for m in ("unet", "controlnet", "text_encoder"):
        getattr(models, m).train()
    lora_step()  # warm-up (allocations, kernels)
    lora_s = _timed(lora_step, args.device, args.repeat)
    for m in ("unet", "controlnet", "text_encoder"):
        getattr(models, m).eval()

    mean_strength = 0.55  # E[t/T] for t/T ~ U(0.1, 1.0)
    ddim = RepairSettings()  # the repair step's DDIM settings
    steps = diffusion.steps_for(mean_strength, ddim.num_inference_steps)

    def repair_one() -> None:
        diffusion.repair(
            deg.to(args.device),
            mean_strength,
            torch.Generator().manual_seed(1),
            ddim.num_inference_steps,
            ddim.eta,
        )

    repair_one()
    repair_s = _timed(repair_one, args.device, max(1, args.repeat - 1))
    lora_mean = sum(lora_s) / len(lora_s)
    repair_mean = sum(repair_s) / len(repair_s)
    refresh_s = repair_mean * args.views_per_refresh
    lora_total = lora_mean * args.lora_steps
    repair_total = refresh_s * args.refreshes
    gs_total = None if args.gs_iter_ms is None else args.gs_iter_ms / 1000.0 * args.gs_iterations
    result = {
        "device": args.device,
        "device_name": torch.cuda.get_device_name() if args.device.startswith("cuda") else cpu_name(),
        "size": args.size,
        "comparable_with_paper": args.size == "full" and args.device.startswith("cuda") and res == 512,
        "resolution": res,
        "precision": str(weight_dtype).replace("torch.", ""),
        "threads": torch.get_num_threads(),
        "parameters_m": {
            k: round(sum(p.numel() for p in m.parameters()) / 1e6, 2) for k, m in models.modules().items()
        },
        "lora_parameters_m": round(sum(counts.values()) / 1e6, 3),
        "build_s": round(build_s, 2),
        "lora_step_s": [round(x, 4) for x in lora_s],
        "repair_view_s": [round(x, 4) for x in repair_s],
        "repair_ddim_steps": steps,
        "refresh_s": round(refresh_s, 3),
        "extrapolated_min": {
            "lora_tuning": round(lora_total / 60, 2),
            "repair_refreshes": round(repair_total / 60, 2),
            "repair_gaussian_iterations": None if gs_total is None else round(gs_total / 60, 2),
            "total": None if gs_total is None else round((lora_total + repair_total + gs_total) / 60, 2),
        },
        "paper_rtx3090_min": {"lora_tuning": 15, "gaussian_repair": 14},
        "settings": {
            "lora_steps": args.lora_steps,
            "refreshes": args.refreshes,
            "views_per_refresh": args.views_per_refresh,
            "gs_iterations": args.gs_iterations,
        },
    }
    text = json.dumps(result, indent=2)
    print(text)
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text + "\n", encoding="utf-8")
    if not math.isfinite(lora_mean):
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
