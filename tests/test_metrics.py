"""PSNR known values, the paper evaluation protocol (white compositing, means, unavailable LPIPS)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from go_core.metrics.evaluate import MetricSuite, composite, error_map, mean_metrics
from go_core.metrics.psnr import psnr


def test_psnr_known_values():
    a = torch.zeros(8, 8, 3, dtype=torch.float64)
    assert psnr(a, a + 0.1) == pytest.approx(20.0, abs=1e-9)  # MSE 0.01
    assert psnr(a, a + 0.5) == pytest.approx(10 * math.log10(4.0), abs=1e-9)
    b = a.clone()
    b[0, 0, 0] = 1.0  # one squared error of 1 over 192 values
    assert psnr(a, b) == pytest.approx(10 * math.log10(192.0), abs=1e-9)
    assert psnr(a, a) == math.inf


def test_psnr_masked_counts_only_mask_pixels():
    a = torch.zeros(4, 4, 3, dtype=torch.float64)
    b = a.clone()
    b[:2] = 0.1  # error only in the top half
    mask = torch.zeros(4, 4)
    mask[:2] = 1
    assert psnr(a, b, mask) == pytest.approx(20.0, abs=1e-9)
    assert psnr(a, b) == pytest.approx(10 * math.log10(1 / 0.005), abs=1e-9)


def test_composite_on_white():
    img = np.full((2, 2, 3), 0.2, np.float32)
    mask = np.array([[1.0, 0.0], [0.5, 0.25]], np.float32)
    out = composite(img, mask, 1.0)
    np.testing.assert_allclose(out[..., 0], [[0.2, 1.0], [0.6, 0.8]], atol=1e-6)
    np.testing.assert_array_equal(composite(img, None), img)


def test_suite_without_weights_reports_unavailable_never_a_number(tmp_path):
    suite = MetricSuite.load(("vgg", "alex"), root=tmp_path)  # empty cache
    assert suite.lpips == {}
    assert set(suite.unavailable) == {"vgg", "alex"}
    assert "go-pipeline weights fetch" in suite.unavailable["vgg"]
    rng = np.random.default_rng(0)
    gt = rng.random((16, 16, 3)).astype(np.float32)
    res = suite.evaluate(np.clip(gt + 0.1, 0, 1), gt, mask=np.ones((16, 16), np.float32), masked=True)
    assert res["lpips_vgg"] is None and res["lpips_alex"] is None and res["lpips_star"] is None
    assert res["masked"]["lpips_vgg"] is None
    assert res["psnr"] > 0 and 0 < res["ssim"] < 1
    assert suite.status()["vgg"].startswith("unavailable")


def test_suite_with_random_weights_lpips_star_and_masked():
    from go_core.metrics.lpips import LPIPS

    torch.manual_seed(0)
    model = LPIPS("alex")
    for lin in model.lin:
        lin.weight.data.abs_()
    suite = MetricSuite(lpips={"vgg": model, "alex": model})
    rng = np.random.default_rng(0)
    gt = rng.random((64, 64, 3)).astype(np.float32)
    pred = gt.copy()
    pred[32:] = rng.random((32, 64, 3))
    mask = np.zeros((64, 64), np.float32)
    mask[:32] = 1  # the unchanged half
    res = suite.evaluate(pred, gt, mask, masked=True)
    assert res["lpips_star"] == pytest.approx(100 * res["lpips_vgg"])
    assert res["masked"]["psnr"] is None  # identical under the mask: PSNR inf stored as None
    assert res["masked"]["lpips_vgg"] < res["lpips_vgg"]


def test_mean_metrics_skips_none():
    rows = [{"psnr": 20.0, "ssim": 0.5, "lpips_vgg": None}, {"psnr": 30.0, "ssim": 0.7, "lpips_vgg": None}]
    m = mean_metrics(rows)
    assert m["psnr"] == pytest.approx(25.0) and m["ssim"] == pytest.approx(0.6)
    assert m["lpips_vgg"] is None and m["lpips_star"] is None


def test_error_map_is_colour_coded():
    gt = np.zeros((4, 4, 3), np.float32)
    pred = gt.copy()
    pred[0, 0] = 1.0
    em = error_map(pred, gt)
    assert em.dtype == np.uint8 and em.shape == (4, 4, 3)
    assert em[0, 0].astype(int).sum() > em[1, 1].astype(int).sum()


def test_compare_command(shared_data, capsys, tmp_path):
    """`go-pipeline compare` on the LPIPS reference pair: PSNR recomputed here, LPIPS-alex the reference."""
    import json

    from PIL import Image

    from go_core.metrics.lpips_weights import weights_path
    from go_pipeline.cli import main

    a, b = shared_data / "lpips_ref" / "ex_ref.png", shared_data / "lpips_ref" / "ex_p1.png"
    assert main(["compare", str(a), str(b), "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    ia, ib = (torch.from_numpy(np.asarray(Image.open(p).convert("RGB"), np.float32) / 255) for p in (a, b))
    assert res["psnr"] == pytest.approx(psnr(ia, ib), abs=1e-9)
    if weights_path("alex").exists():
        assert res["lpips_alex"] == pytest.approx(0.138, abs=0.002)
    assert main(["compare", str(a), str(b)]) == 0
    assert "PSNR" in capsys.readouterr().out
    Image.new("RGB", (10, 12)).save(tmp_path / "small.png")
    assert main(["compare", str(a), str(tmp_path / "small.png")]) == 2
    assert "image sizes differ" in capsys.readouterr().err


def test_lpips_is_none_for_images_too_small_for_the_backbone():
    from go_core.metrics.lpips import LPIPS

    suite = MetricSuite(lpips={"vgg": LPIPS("vgg"), "alex": LPIPS("alex")})
    img = np.random.default_rng(0).random((24, 24, 3)).astype(np.float32)
    res = suite.evaluate(img, img * 0.5)
    assert res["lpips_alex"] is None and res["lpips_vgg"] is not None
