"""Training curves as CSV (one row per logged iteration), like nerfstudio's / TensorBoard's scalars:
``iteration, loss, train_psnr, gaussians`` and then the loss parts (l1, ssim, mask_bce, ...)."""

from __future__ import annotations

import csv
import io
from pathlib import Path

FIRST = ("iteration", "loss", "train_psnr", "gaussians")
RENAMED = {"step": "iteration", "psnr": "train_psnr", "n": "gaussians"}


def curves_csv(loss_log: list[dict]) -> str:
    """The CSV text of a training loss log (``TrainStats.loss_log`` entries: step, loss, n, psnr, parts)."""
    rows = [{RENAMED.get(k, k): v for k, v in entry.items()} for entry in loss_log]
    extra = sorted({k for r in rows for k in r} - set(FIRST))
    out = io.StringIO()
    writer = csv.DictWriter(out, fieldnames=[*FIRST, *extra], lineterminator="\n", restval="")
    writer.writeheader()
    writer.writerows(rows)
    return out.getvalue()


def write_curves(path: str | Path, loss_log: list[dict]) -> Path:
    from go_core.io.atomic import atomic_write_text

    return atomic_write_text(path, curves_csv(loss_log))
