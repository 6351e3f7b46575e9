"""The SSIM metric reuses the 3DGS training SSIM; cross-checked against scikit-image."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from skimage.metrics import structural_similarity

from go_core.coarse.losses import ssim as loss_ssim
from go_core.metrics.ssim import ssim


def _sk(a, b):
    return structural_similarity(
        a, b, gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1, channel_axis=2
    )


@pytest.mark.parametrize("shape", [(48, 64), (97, 80), (128, 128)])
def test_ssim_valid_border_matches_skimage(shape):
    rng = np.random.default_rng(sum(shape))
    a = rng.random((*shape, 3))
    for b in (np.clip(a + 0.15 * rng.standard_normal(a.shape), 0, 1), rng.random(a.shape)):
        ours = ssim(torch.from_numpy(a), torch.from_numpy(b), border="valid")
        assert abs(ours - _sk(a, b)) < 1e-3
        assert ours == pytest.approx(_sk(a, b), abs=1e-9)  # in fact equal to float64 precision


def test_ssim_padded_is_the_training_ssim_and_close_to_skimage_on_large_images():
    rng = np.random.default_rng(3)
    a = rng.random((256, 256, 3))
    b = np.clip(a + 0.1 * rng.standard_normal(a.shape), 0, 1)
    ours = ssim(torch.from_numpy(a), torch.from_numpy(b))
    ref_loss = float(loss_ssim(torch.from_numpy(a).double(), torch.from_numpy(b).double()))
    assert ours == pytest.approx(ref_loss, abs=1e-12)
    # zero padding only changes the 5-px border: still within 1e-2 of scikit-image at 256 px
    assert abs(ours - _sk(a, b)) < 1e-2


def test_ssim_identical_and_mask_weighting():
    rng = np.random.default_rng(1)
    a = torch.from_numpy(rng.random((40, 40, 3)))
    assert ssim(a, a) == pytest.approx(1.0, abs=1e-12)
    b = a.clone()
    b[:, 20:] = torch.from_numpy(rng.random((40, 20, 3)))  # right half differs
    left = torch.zeros(40, 40)
    left[:, :10] = 1.0  # far from the changed half (window radius 5)
    assert ssim(a, b, mask=left) == pytest.approx(1.0, abs=1e-9)
    assert ssim(a, b) < 0.8
