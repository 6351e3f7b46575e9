"""Training curves: the CSV the coarse and repair steps write, and the train PSNR it holds."""

from __future__ import annotations

import csv
import io
import math
from types import SimpleNamespace

import torch

from go_core.coarse.loop import train_psnr, view_target
from go_core.io.curves import curves_csv


def test_curves_csv_columns_and_rows():
    log = [
        {"step": 100, "loss": 0.5, "n": 1000, "psnr": 12.5, "l1": 0.3, "ssim": 0.4},
        {"step": 200, "loss": 0.25, "n": 1500, "psnr": 15.0, "l1": 0.2, "ssim": 0.6, "mask_bce": 0.1},
    ]
    rows = list(csv.DictReader(io.StringIO(curves_csv(log))))
    assert list(rows[0]) == ["iteration", "loss", "train_psnr", "gaussians", "l1", "mask_bce", "ssim"]
    assert rows[0]["mask_bce"] == "" and rows[1]["mask_bce"] == "0.1"
    assert [int(r["iteration"]) for r in rows] == [100, 200] and rows[1]["gaussians"] == "1500"


def test_train_psnr_against_the_masked_target():
    image = torch.rand(8, 8, 3, generator=torch.Generator().manual_seed(0))
    mask = (torch.arange(64).reshape(8, 8) % 2).float()
    view = SimpleNamespace(image=image, mask=mask)
    bg = torch.tensor([1.0, 0.0, 0.5])
    target = view_target(view, bg)
    assert torch.equal(target[0, 1], image[0, 1]) and torch.equal(target[0, 0], bg)
    out = SimpleNamespace(rgb=(target + 0.1)[None])  # every channel off by 0.1: MSE 0.01, PSNR 20 dB
    assert math.isclose(train_psnr(out, view, bg), 20.0, abs_tol=1e-4)
    assert train_psnr(SimpleNamespace(rgb=target[None]), view, bg) == 100.0
