"""Train the repair prior (go_core.compact.prior) on the repair corpus: coarse novel-view render -> truth.

Input per pair: the coarse render on white + its alpha + (``--reference``) the nearest training view by
viewing direction, warped into the novel view through the coarse depth (default) or raw. Target: the true
render on white and the true alpha. Loss: L1(rgb) (``--inside-weight``: the pixels inside the true
silhouette weighted up) + ``--lpips`` · LPIPS(rgb) (the project's LPIPS, ``--lpips-net`` vgg by default) +
``--alpha-weight`` · L1(alpha). ``--train-view-share S`` draws that share of the samples from the pairs at
the training views (coarse render -> its photo, reference the nearest other training view, warped through
the coarse depth there): renders that are already right, which the prior should leave alone
(``--val-train-views`` scores the held-out objects there too). ``--init PRIOR`` fine-tunes a trained
prior instead of starting afresh.
Augmentation: random crops, horizontal flips and RGB channel permutations (applied to input, reference and
target alike). Deterministic for a seed on CPU; resumable (``<out>/checkpoint.safetensors``, kept at the last
step too, so a run with a larger ``--steps`` trains on from a finished one, Adam state and all). Needs torch,
numpy and this repository on PYTHONPATH (no other package); LPIPS weights from ``--lpips-weights`` or the
go-pipeline cache. Runs on a GPU with ``--device cuda``; the weights written are the same kind of file
either way. Example (1 CPU thread)::

    python benchmarks/prior/train_repair_prior.py --corpus ~/go-corpus --out prior_run \\
        --steps 2000 --batch 4 --crop 128

Writes ``<out>/prior.safetensors`` (weights + config + training facts in the metadata) and
``<out>/train_log.json`` (loss curve, validation PSNR / LPIPS* / alpha IoU of the coarse input and the
restored output, per held-out object: the val split, and the train objects of any family ``--families``
leaves out; settings, CPU time).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from go_core.compact.prior import PriorConfig, RepairPrior, prior_input, save_prior
from go_core.compact.reference import nearest_view, reproject
from go_core.seeding import numpy_rng, seeded_torch_init

KEYS = ("inp", "alpha", "ref", "ref_alpha", "tgt", "tgt_alpha")


def _on_white(rgba: np.ndarray) -> np.ndarray:
    a = rgba[..., 3:4].astype(np.float32) / 255.0
    return (rgba[..., :3].astype(np.float32) / 255.0) * a + (1.0 - a)


def _references(d, mode: str, views: str = "novel") -> tuple[np.ndarray, np.ndarray]:
    """The reference input of every pair of one object: the nearest training view, raw or reprojected
    through the coarse depth (go_core.compact.reference); [N, H, W, 3] on white and [N, H, W, 1].
    ``views="train"``: the pairs at the training views, whose reference is the nearest *other* one."""
    c2w = d[f"{views}_c2w"]
    near = nearest_view(c2w, d["train_c2w"], np.arange(len(c2w)) if views == "train" else None)
    train_rgb = _on_white(d["train_rgba"])
    train_alpha = d["train_rgba"][..., 3].astype(np.float32) / 255.0
    if mode == "nearest":
        return train_rgb[near], train_alpha[near][..., None]
    rgbs, alphas = [], []
    for i, j in enumerate(near):
        cov = d[f"{views}_coarse_alpha"][i].astype(np.float32) / 255.0
        args = (d["intrinsics"], c2w[i], d["train_c2w"][j], train_rgb[j], train_alpha[j])
        rgb, a = reproject(d[f"{views}_coarse_depth"][i], cov, *args)
        rgbs.append(rgb)
        alphas.append(a[..., None])
    return np.stack(rgbs), np.stack(alphas)


def _wanted(info: dict, split: str, families: list[str] | None) -> bool:
    """Split ``train``: the train objects of ``families`` (default all). Split ``held_out``: every object
    the training never sees, the val objects and the train objects of the families left out."""
    family = info["name"].split("/")[0]
    in_families = not families or family in families
    if split == "held_out":
        return info["split"] == "val" or not in_families
    return info["split"] == split and in_families


def _object_pairs(d, reference: str, views: str) -> dict[str, np.ndarray]:
    """One object's pairs at its ``views`` ("novel": the corpus's novel views; "train": the training
    views, where the coarse render is nearly right) as float32 arrays [N, H, W, C] in [0, 1]."""
    truth = d[f"{views}_rgba"]
    n, h, w = truth.shape[:3]
    if reference == "none":
        ref, ref_alpha = np.ones((n, h, w, 3), np.float32), np.zeros((n, h, w, 1), np.float32)
    else:
        ref, ref_alpha = _references(d, reference, views)
    return {
        "inp": d[f"{views}_coarse_rgb"].astype(np.float32) / 255.0,
        "alpha": d[f"{views}_coarse_alpha"][..., None].astype(np.float32) / 255.0,
        "ref": ref,
        "ref_alpha": ref_alpha,
        "tgt": _on_white(truth),
        "tgt_alpha": truth[..., 3:4].astype(np.float32) / 255.0,
    }


def load_split(
    corpus: Path,
    split: str,
    reference: str = "reprojected",
    families: list[str] | None = None,
    only: list[str] | None = None,
    views: str = "novel",
) -> dict:
    """Every pair at ``views`` (``_object_pairs``) of the finished objects of ``split`` (``_wanted``; of
    ``only`` when given) as float32 arrays [N, H, W, C] in [0, 1] and the object of each pair."""
    names, parts = [], {k: [] for k in KEYS}
    for info_path in sorted((corpus / "objects").glob("*/object.json")):
        info = json.loads(info_path.read_text())
        if not _wanted(info, split, families) or (only is not None and info["name"] not in only):
            continue
        with np.load(info_path.parent / "pairs.npz") as d:
            if views == "train" and "train_coarse_depth" not in d.files:
                sys.exit(
                    f"error: {info_path.parent / 'pairs.npz'}: no train_coarse_depth (made before it was "
                    "stored): run benchmarks/prior/repair_corpus.py --out CORPUS --add-train-depth"
                )
            pairs = _object_pairs(d, reference, views)
        for k in KEYS:
            parts[k].append(pairs[k])
        names += [info["name"]] * len(pairs["inp"])
    if not names:
        sys.exit(f"error: {corpus}: no finished object of split {split!r} (objects/*/object.json)")
    return {"names": names, **{k: np.concatenate(v) for k, v in parts.items()}}


# validation figures per object: of the coarse input (_in) and the restored output (_out); PSNR over the
# image and inside / outside the true silhouette (true alpha > 0.5)
VAL_KEYS = tuple(
    f"{k}_{t}" for k in ("psnr", "psnr_inside", "psnr_outside", "lp", "iou") for t in ("in", "out")
)


def draw_batch(
    data: dict,
    rng: np.random.Generator,
    batch: int,
    crop: int,
    extra: dict | None = None,
    share: float = 0.0,
) -> dict[str, torch.Tensor]:
    """A random batch: crops, horizontal flips and RGB permutations shared by input, reference and target.
    With ``share`` > 0 each sample comes from ``extra`` (the training-view pairs) with that probability."""
    h, w = data["inp"].shape[1:3]
    out: dict[str, list] = {k: [] for k in KEYS}
    for _ in range(batch):
        source = extra if share > 0 and rng.random() < share else data
        i = int(rng.integers(len(source["inp"])))
        y, x = int(rng.integers(h - crop + 1)), int(rng.integers(w - crop + 1))
        flip = bool(rng.random() < 0.5)
        perm = rng.permutation(3)
        for k in KEYS:
            a = source[k][i, y : y + crop, x : x + crop]
            if flip:
                a = a[:, ::-1]
            if a.shape[-1] == 3:
                a = a[..., perm]
            out[k].append(a)
    return {
        k: torch.from_numpy(np.ascontiguousarray(np.stack(v))).permute(0, 3, 1, 2) for k, v in out.items()
    }


def model_input(b: dict[str, torch.Tensor], reference: bool) -> torch.Tensor:
    return prior_input(b["inp"], b["alpha"], *((b["ref"], b["ref_alpha"]) if reference != "none" else ()))


def rgb_l1(
    rgb: torch.Tensor, target: torch.Tensor, target_alpha: torch.Tensor, inside: float
) -> torch.Tensor:
    """L1 of the RGB; with ``inside`` != 1 a weighted mean whose pixels inside the true silhouette count
    ``inside`` times (weight 1 + (inside - 1) · true alpha): the object's surface against its background."""
    if inside == 1.0:
        return F.l1_loss(rgb, target)
    weight = (1.0 + (inside - 1.0) * target_alpha).expand_as(rgb)
    return (weight * (rgb - target).abs()).sum() / weight.sum()


def loss_terms(model, lpips, b: dict[str, torch.Tensor], args) -> dict[str, torch.Tensor]:
    rgb, alpha = model(model_input(b, args.reference))
    terms = {
        "l1": rgb_l1(rgb, b["tgt"], b["tgt_alpha"], args.inside_weight),
        "alpha": F.l1_loss(alpha, b["tgt_alpha"]),
    }
    if lpips is not None and args.lpips > 0:
        terms["lpips"] = lpips(rgb * 2 - 1, b["tgt"] * 2 - 1).mean()
    terms["total"] = (
        terms["l1"] + args.alpha_weight * terms["alpha"] + args.lpips * terms.get("lpips", torch.zeros(()))
    )
    return terms


@torch.no_grad()
def evaluate(model, lpips, data: dict, args, device: str) -> dict:
    """Validation: PSNR (over the image, inside and outside the true silhouette), LPIPS* (x100) and alpha
    IoU of the coarse input and of the restored output, per object and overall (full-size images, no
    augmentation)."""
    model.eval()
    rows: dict[str, dict[str, list]] = {}
    for i in range(len(data["names"])):
        b = {k: torch.from_numpy(data[k][i : i + 1]).permute(0, 3, 1, 2).to(device) for k in KEYS}
        rgb, alpha = model(model_input(b, args.reference))
        row = rows.setdefault(data["names"][i], {k: [] for k in VAL_KEYS})
        inside = (b["tgt_alpha"] > 0.5).expand_as(b["tgt"])
        for tag, img, a in (("in", b["inp"], b["alpha"]), ("out", rgb, alpha)):
            sq = (img - b["tgt"]) ** 2
            for key, where in (("psnr", None), ("psnr_inside", inside), ("psnr_outside", ~inside)):
                mse = (sq.mean() if where is None else sq[where].mean()).clamp_min(1e-12)
                row[f"{key}_{tag}"].append(float(-10 * torch.log10(mse)))
            if lpips is not None:
                row[f"lp_{tag}"].append(100 * float(lpips(img * 2 - 1, b["tgt"] * 2 - 1).mean()))
            t, p = b["tgt_alpha"] > 0.5, a > 0.5
            row[f"iou_{tag}"].append(float((t & p).sum() / (t | p).sum().clamp_min(1)))
    model.train()
    per_object = {n: {k: _mean(v) for k, v in r.items()} for n, r in rows.items()}
    keys = next(iter(per_object.values())).keys()
    mean = {k: _mean([o[k] for o in per_object.values() if o[k] is not None]) for k in keys}
    return {"mean_over_objects": mean, "per_object": per_object}


def _mean(values: list[float]) -> float | None:
    return round(float(np.mean(values)), 4) if values else None


def load_lpips(net: str, weights: Path | None, device: str):
    """The project's LPIPS with genuine weights (``weights``, else the go-pipeline cache), frozen."""
    from go_core.metrics.lpips import LPIPS
    from go_core.metrics.lpips_weights import load_lpips_state

    model = LPIPS(net)
    if weights is None:
        model.load_state_dict(load_lpips_state(net), strict=True)
    else:
        from safetensors.torch import load_file

        model.load_state_dict(load_file(str(weights)), strict=True)
    return model.to(device)


def _save_checkpoint(path: Path, model, opt, meta: dict) -> None:
    """Weights and Adam moments as tensors; ``meta`` (step, numpy RNG state, loss log, CPU s, the training
    objects) as JSON metadata."""
    from go_core.io.safetensors_file import write_safetensors

    tensors = {f"model.{k}": v.detach().cpu() for k, v in model.state_dict().items()}
    for i, p in enumerate(model.parameters()):
        st = opt.state.get(p)
        if st:
            tensors[f"adam.{i}.m"] = st["exp_avg"].cpu()
            tensors[f"adam.{i}.v"] = st["exp_avg_sq"].cpu()
    write_safetensors(path, tensors, {"state": json.dumps(meta)})


def _load_checkpoint(path: Path, model, opt, device: str) -> dict:
    from safetensors.torch import safe_open

    with safe_open(str(path), framework="pt") as f:
        meta = json.loads(f.metadata()["state"])
        tensors = {k: f.get_tensor(k) for k in f.keys()}  # noqa: SIM118
    model.load_state_dict({k[6:]: v for k, v in tensors.items() if k.startswith("model.")})
    for i, p in enumerate(model.parameters()):
        if f"adam.{i}.m" in tensors:
            opt.state[p] = {
                "step": torch.tensor(float(meta["step"])),
                "exp_avg": tensors[f"adam.{i}.m"].to(device),
                "exp_avg_sq": tensors[f"adam.{i}.v"].to(device),
            }
    return meta


def _resume(args, model, opt, rng: np.random.Generator) -> dict:
    """The run's state: fresh, or from ``<out>/checkpoint.safetensors`` (weights, Adam and RNG restored in
    place; the objects the run started with, as the corpus may have grown since)."""
    ckpt = args.out / "checkpoint.safetensors"
    if not ckpt.exists():
        return {"step": 0, "log": [], "cpu_s": 0.0, "objects": None}
    meta = _load_checkpoint(ckpt, model, opt, args.device)
    rng.bit_generator.state = meta["rng"]
    return {k: meta[k] for k in ("step", "log", "cpu_s", "objects")}


def learning_rate(args, step: int) -> float:
    """The step's learning rate: constant, or cosine from ``--lr`` down to ``--lr-floor`` x ``--lr`` at
    ``--steps`` (a function of the step alone, so a resumed run follows the same schedule)."""
    if args.lr_decay == "none":
        return args.lr
    floor = args.lr_floor * args.lr
    return floor + 0.5 * (args.lr - floor) * (1.0 + math.cos(math.pi * min(step, args.steps) / args.steps))


def _run_steps(args, model, lpips, opt, rng, data: dict, state: dict, train_views: dict | None) -> bool:
    """Optimise from ``state["step"]`` to ``args.steps``; False when stopped early by ``--budget-min`` (at a
    checkpoint). ``state`` is updated in place (step, loss log, CPU seconds)."""
    t0, wall0, cpu0, running = time.process_time(), time.perf_counter(), state["cpu_s"], []
    share = args.train_view_share
    for step in range(state["step"] + 1, args.steps + 1):
        batch = draw_batch(data, rng, args.batch, args.crop, train_views, share)
        b = {k: v.to(args.device) for k, v in batch.items()}
        for group in opt.param_groups:
            group["lr"] = learning_rate(args, step)
        terms = loss_terms(model, lpips, b, args)
        opt.zero_grad(set_to_none=True)
        terms["total"].backward()
        opt.step()
        running.append({k: float(v.detach()) for k, v in terms.items()})
        state["step"], state["cpu_s"] = step, cpu0 + time.process_time() - t0
        if step % args.log_every == 0 or step == args.steps:
            state["log"].append(
                {"step": step, **{k: round(float(np.mean([r[k] for r in running])), 5) for k in running[0]}}
            )
            running = []
            print(json.dumps(state["log"][-1]), flush=True)
        if args.checkpoint_every and (step % args.checkpoint_every == 0 or step == args.steps):
            # the last step too: a later run with a larger --steps trains on from it, Adam state and all
            _save_checkpoint(
                args.out / "checkpoint.safetensors", model, opt, {**state, "rng": rng.bit_generator.state}
            )
            if step < args.steps and args.budget_min and (time.perf_counter() - wall0) / 60 > args.budget_min:
                print(
                    f"stopped at step {step} of {args.steps} (--budget-min): run again to resume", flush=True
                )
                return False
    return True


def train(args) -> dict:
    """Train (or resume) and, when the last step is reached, validate and write the weights and the log."""
    if args.checkpoint_every % args.log_every:
        sys.exit("error: --checkpoint-every must be a multiple of --log-every (the loss log resumes there)")
    with seeded_torch_init(args.seed, "prior_init"):
        model = RepairPrior(
            PriorConfig(width=args.width, levels=args.levels, reference=args.reference != "none")
        )
    model = model.to(args.device)
    use_lpips = args.lpips > 0 or not args.no_lpips_eval
    lpips = load_lpips(args.lpips_net, args.lpips_weights, args.device) if use_lpips else None
    opt = torch.optim.Adam(model.parameters(), lr=args.lr)
    rng = numpy_rng(args.seed, "prior_batches")
    args.out.mkdir(parents=True, exist_ok=True)
    state = _resume(args, model, opt, rng)
    if state["step"] == 0 and args.init is not None:  # fine-tune a trained prior (fresh optimiser and log)
        from go_core.compact.prior import load_prior

        init = load_prior(args.init)
        if init.config != model.config:
            sys.exit(f"error: --init {args.init}: config {init.config} is not this run's {model.config}")
        model.load_state_dict(init.state_dict())
    start = state["step"]
    data = load_split(args.corpus, "train", args.reference, args.families, state["objects"])
    state["objects"] = sorted(set(data["names"]))
    train_views = None
    if args.train_view_share > 0:
        train_views = load_split(
            args.corpus, "train", args.reference, args.families, state["objects"], "train"
        )
    if not _run_steps(args, model, lpips, opt, rng, data, state, train_views):
        return {"stopped_at": state["step"], "cpu_s_total": round(state["cpu_s"], 1)}
    result = {
        "command": "python benchmarks/prior/train_repair_prior.py " + " ".join(sys.argv[1:]),
        "settings": {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()},
        "loss_log": state["log"],
        "train_pairs": len(data["names"]),
        "train_view_pairs": len(train_views["names"]) if train_views else 0,
        "train_objects": state["objects"],
        "cpu_s_total": round(state["cpu_s"], 1),
        "resumed_from": start,
    }
    if not args.no_val:
        val = load_split(args.corpus, "held_out", args.reference, args.families)
        result["validation"] = evaluate(model, lpips, val, args, args.device)
        if args.train_view_share > 0 or args.val_train_views:
            val = load_split(args.corpus, "held_out", args.reference, args.families, views="train")
            result["validation_train_views"] = evaluate(model, lpips, val, args, args.device)
    extra = {"steps": args.steps, "train_objects": state["objects"]}
    save_prior(args.out / "prior.safetensors", model.cpu(), extra)
    (args.out / "train_log.json").write_text(json.dumps(result, indent=1))
    return result


def parse_args(argv=None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--corpus", type=Path, required=True)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--device", default="cpu", choices=["cpu", "cuda"])
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--batch", type=int, default=4)
    ap.add_argument("--crop", type=int, default=128)
    ap.add_argument("--lr", type=float, default=2e-4)
    ap.add_argument("--lr-decay", default="none", choices=["none", "cosine"], help="learning-rate schedule")
    ap.add_argument("--lr-floor", type=float, default=0.05, help="cosine: the last step's lr / --lr")
    ap.add_argument("--width", type=int, default=32)
    ap.add_argument("--levels", type=int, default=3)
    ap.add_argument(
        "--reference",
        default="reprojected",
        choices=["none", "nearest", "reprojected"],
        help="second input: none, the nearest training view raw, or warped through the coarse depth",
    )
    ap.add_argument("--families", nargs="*", default=None, help="asset families to use (default: all)")
    ap.add_argument("--lpips", type=float, default=0.2, help="weight of the LPIPS term (0: L1 only)")
    ap.add_argument("--lpips-net", default="vgg", choices=["vgg", "alex"])
    ap.add_argument("--lpips-weights", type=Path, default=None, help="LPIPS safetensors (default: the cache)")
    ap.add_argument("--no-lpips-eval", action="store_true", help="no LPIPS at all when --lpips is 0")
    ap.add_argument("--alpha-weight", type=float, default=0.5)
    ap.add_argument("--inside-weight", type=float, default=1.0, help="RGB L1 weight of the object's pixels")
    ap.add_argument(
        "--train-view-share",
        type=float,
        default=0.0,
        help="share of the samples drawn from the training views (coarse render nearly right: leave it)",
    )
    ap.add_argument(
        "--val-train-views", action="store_true", help="validate at the held-out training views too"
    )
    ap.add_argument("--init", type=Path, default=None, help="start from this prior's weights (fine-tune)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--log-every", type=int, default=20)
    ap.add_argument("--checkpoint-every", type=int, default=200)
    ap.add_argument("--no-val", action="store_true")
    ap.add_argument(
        "--budget-min", type=float, default=0.0, help="stop at a checkpoint after this (0: never)"
    )
    return ap.parse_args(argv)


if __name__ == "__main__":
    a = parse_args()
    if a.device == "cuda" and not torch.cuda.is_available():
        sys.exit("error: --device cuda: torch sees no CUDA device")
    train(a)
