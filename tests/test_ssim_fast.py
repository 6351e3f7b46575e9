"""The compiled SSIM loss kernel (go_core/kernels/csrc/ssim.cpp) against the float64 torch reference.

``go_core.coarse.losses.ssim`` runs the kernel for one float32 CPU image pair; ``ssim_map`` (torch, autograd)
is the reference, itself checked against scikit-image and finite differences in tests/test_losses.py.
"""

from __future__ import annotations

import pytest
import torch

from go_core.coarse.losses import SSIM_C1, SSIM_C2, _window64, ssim, ssim_map

pytestmark = pytest.mark.usefixtures("single_thread")  # small tensors: one thread is faster

FWD_ABS = 1e-6  # forward: float64 kernel sums rounded to float32 (measured ~1e-9)
GRAD_REL = 1e-6  # gradient, relative in norm: float32 rounding of the output (measured ~4e-8)


@pytest.fixture(scope="module", autouse=True)
def cpu_ext():
    """Build (or load the cached) compiled extension once; it registers torch.ops.go_ssim."""
    from go_core.render.build import load_extension

    return load_extension()


def _images(kind: str, h: int, w: int, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    """A float32 [H,W,3] pair (prediction, target) of the named kind."""
    g = torch.Generator().manual_seed(seed)
    rand = torch.rand(h, w, 3, generator=g)
    if kind == "noisy":  # a prediction close to its target, as in training
        return rand, (rand + 0.1 * torch.randn(h, w, 3, generator=g)).clamp(0, 1)
    if kind == "random":
        return rand, torch.rand(h, w, 3, generator=g)
    if kind == "constants":
        return torch.full((h, w, 3), 0.3), torch.full((h, w, 3), 0.7)
    if kind == "zeros_ones":
        return torch.zeros(h, w, 3), torch.ones(h, w, 3)
    if kind == "ones_zeros":
        return torch.ones(h, w, 3), torch.zeros(h, w, 3)
    if kind == "zeros_random":
        return torch.zeros(h, w, 3), rand
    if kind == "random_ones":
        return rand, torch.ones(h, w, 3)
    raise ValueError(kind)


def _reference(x: torch.Tensor, y: torch.Tensor) -> tuple[float, torch.Tensor]:
    """Float64 mean of the torch reference map and its autograd gradient w.r.t. x, [H,W,3]."""
    xd = x.double().permute(2, 0, 1)[None].requires_grad_(True)
    value = ssim_map(xd, y.double().permute(2, 0, 1)[None]).mean()
    value.backward()
    return value.item(), xd.grad[0].permute(1, 2, 0)


def _kernel(x: torch.Tensor, y: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Through the public ``ssim`` exactly as training calls it: value and gradient w.r.t. x."""
    xr = x.clone().requires_grad_(True)
    value = ssim(xr.permute(2, 0, 1)[None], y.permute(2, 0, 1)[None])
    assert type(value.grad_fn).__name__ == "_SSIMKernelBackward"
    value.backward()
    return value.detach(), xr.grad


SIZES = [(256, 256), (7, 13), (13, 7), (1, 1), (4, 3), (10, 10), (11, 11), (12, 40), (97, 61)]
KINDS = ["noisy", "random", "constants", "zeros_ones", "ones_zeros", "zeros_random", "random_ones"]


@pytest.mark.parametrize("size", SIZES, ids=lambda s: f"{s[0]}x{s[1]}")
@pytest.mark.parametrize("kind", KINDS)
def test_kernel_matches_float64_reference(kind, size):
    x, y = _images(kind, *size, seed=size[0] * 1000 + size[1])
    ref_value, ref_grad = _reference(x, y)
    value, grad = _kernel(x, y)
    assert value.dtype == torch.float32 and grad.dtype == torch.float32 and grad.shape == x.shape
    assert abs(value.item() - ref_value) <= FWD_ABS
    err = (grad.double() - ref_grad).norm().item()
    assert err <= GRAD_REL * ref_grad.norm().item()


@pytest.mark.parametrize("size", [(256, 256), (7, 13), (1, 1)], ids=lambda s: f"{s[0]}x{s[1]}")
def test_identical_images_give_one_and_zero_gradient(size):
    x, _ = _images("random", *size)
    value, grad = _kernel(x, x.clone())
    assert value.item() == pytest.approx(1.0, abs=1e-7)
    assert grad.abs().max().item() <= 1e-9  # exactly 0 in exact arithmetic (a maximum of SSIM)


def test_partials_and_value_in_float64_match_reference_closely():
    """The raw op returns the mean in float64: the kernel computes in double throughout."""
    x, y = _images("noisy", 64, 48)
    mean, partials = torch.ops.go_ssim.forward(x, y, _window64(), SSIM_C1, SSIM_C2, False)
    assert mean.dtype == torch.float64 and partials.numel() == 0
    assert mean.item() == pytest.approx(_reference(x, y)[0], abs=1e-13)
    mean_g, partials_g = torch.ops.go_ssim.forward(x, y, _window64(), SSIM_C1, SSIM_C2, True)
    assert partials_g.shape == (3, 64, 48 * 3) and mean_g.item() == pytest.approx(mean.item(), abs=1e-15)


@pytest.mark.parametrize("size", [(256, 256), (131, 97)], ids=lambda s: f"{s[0]}x{s[1]}")
def test_one_and_two_threads_are_bit_identical(size):
    """Both sizes are above the kernel's serial cut-off (32k values), so 2 threads split the rows."""
    x, y = _images("noisy", *size)
    runs = []
    for n in (1, 2, 1):
        torch.set_num_threads(n)
        try:
            runs.append(_kernel(x, y))
        finally:
            torch.set_num_threads(1)
    for value, grad in runs[1:]:
        assert torch.equal(value, runs[0][0]) and torch.equal(grad, runs[0][1])


def test_layouts_and_leaf_gradients_agree():
    """[H,W,3], [1,3,H,W] (channels-first memory: copied) and channels_last give the same value and grads."""
    x, y = _images("noisy", 30, 41)
    leaf_hwc = x.clone().requires_grad_(True)
    v_hwc = ssim(leaf_hwc, y)
    v_hwc.backward()
    leaf_chw = x.permute(2, 0, 1)[None].contiguous().requires_grad_(True)
    v_chw = ssim(leaf_chw, y.permute(2, 0, 1)[None].contiguous())
    v_chw.backward()
    leaf_bhwc = x[None].clone().requires_grad_(True)
    v_bhwc = ssim(leaf_bhwc, y[None], channels_last=True)
    v_bhwc.backward()
    for v in (v_hwc, v_chw, v_bhwc):
        assert type(v.grad_fn).__name__ == "_SSIMKernelBackward"
        assert torch.equal(v, v_hwc)
    assert torch.equal(leaf_chw.grad[0].permute(1, 2, 0), leaf_hwc.grad)
    assert torch.equal(leaf_bhwc.grad[0], leaf_hwc.grad)


def test_upstream_gradient_scales_and_dssim_composes():
    x, y = _images("noisy", 20, 24)
    _, ref_grad = _reference(x, y)
    leaf = x.clone().requires_grad_(True)
    (3.0 - 0.5 * ssim(leaf, y)).backward()  # e.g. λ·(1 - SSIM) inside the photometric loss
    assert (leaf.grad.double() + 0.5 * ref_grad).norm() <= GRAD_REL * 0.5 * ref_grad.norm()


def test_torch_path_where_the_kernel_does_not_apply():
    x, y = _images("noisy", 16, 18)
    ref = ssim_map(x.double(), y.double()).mean()
    cases = {
        "float64": (x.double(), y.double()),
        "batch of two": (torch.stack([x, x]), torch.stack([y, y])),
        "one channel": (x[..., :1].permute(2, 0, 1)[None], y[..., :1].permute(2, 0, 1)[None]),
    }
    for name, (a, b) in cases.items():
        value = ssim(a.requires_grad_(True), b, channels_last=name == "batch of two")
        assert type(value.grad_fn).__name__ != "_SSIMKernelBackward", name
    target = y.clone().requires_grad_(True)  # a target that needs a gradient: both get one, torch path
    value = ssim(x.clone().requires_grad_(True), target)
    value.backward()
    assert target.grad is not None and value.item() == pytest.approx(ref.item(), abs=1e-6)
    with torch.no_grad():  # no gradient wanted anywhere: the kernel, forward only
        assert ssim(x, target).item() == pytest.approx(ref.item(), abs=1e-6)


def test_no_grad_and_grad_forward_agree():
    x, y = _images("random", 33, 20)
    with_grad = ssim(x.clone().requires_grad_(True), y)
    with torch.no_grad():
        without = ssim(x, y)
    assert without.grad_fn is None and without.item() == pytest.approx(with_grad.item(), abs=1e-7)


def test_op_rejects_bad_inputs():
    x, y = _images("random", 8, 8)
    w = _window64()
    with pytest.raises(RuntimeError, match="contiguous float32"):
        torch.ops.go_ssim.forward(x.double(), y, w, SSIM_C1, SSIM_C2, False)
    with pytest.raises(RuntimeError, match="contiguous float32"):
        torch.ops.go_ssim.forward(x.permute(1, 0, 2), y, w, SSIM_C1, SSIM_C2, False)
    with pytest.raises(RuntimeError, match="shapes differ"):
        torch.ops.go_ssim.forward(x, y[:4], w, SSIM_C1, SSIM_C2, False)
    with pytest.raises(RuntimeError, match="11 taps"):
        torch.ops.go_ssim.forward(x, y, w[:9], SSIM_C1, SSIM_C2, False)
    with pytest.raises(RuntimeError, match="channels"):
        torch.ops.go_ssim.forward(
            x[..., :2].contiguous(), y[..., :2].contiguous(), w, SSIM_C1, SSIM_C2, False
        )


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_mask_bce_equals_torch_binary_cross_entropy(dtype):
    """``mask_bce`` (a lerp of two logs, cheaper than F.binary_cross_entropy) has the same value/gradient."""
    import torch.nn.functional as F

    from go_core.coarse.losses import mask_bce

    g = torch.Generator().manual_seed(5)
    alpha = torch.rand(1, 64, 48, 1, generator=g, dtype=dtype)
    alpha[0, 0, :8, 0] = torch.tensor([0.0, 1.0, 1e-9, 1 - 1e-9, 0.5, 1e-6, 1 - 1e-6, 0.25], dtype=dtype)
    for mask in ((torch.rand(64, 48, generator=g) > 0.5).float(), torch.rand(64, 48, generator=g)):
        a1 = alpha.clone().requires_grad_(True)
        ours = mask_bce(a1, mask)
        ours.backward()
        a2 = alpha.clone().requires_grad_(True)
        ref = F.binary_cross_entropy(a2.reshape(64, 48).clamp(1e-6, 1 - 1e-6), mask.to(dtype))
        ref.backward()
        tol = 1e-6 if dtype == torch.float32 else 1e-14
        assert ours.item() == pytest.approx(ref.item(), rel=tol)
        assert (a1.grad - a2.grad).norm() <= tol * a2.grad.norm()
        assert a1.grad[0, 0, 0, 0] == 0 and a1.grad[0, 0, 1, 0] == 0  # clamped: no gradient, as torch's
    with pytest.raises(ValueError, match="differ in size"):
        mask_bce(torch.rand(4, 5), torch.rand(4, 4))
