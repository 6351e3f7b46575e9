"""gsplat (CUDA) backend parity with the CPU backend; runs only where CUDA and gsplat are present."""

from __future__ import annotations

import pytest
import torch

from go_core.render import render
from go_core.render.gsplat_backend import gsplat_available
from go_core.render.synthetic import random_scene

pytestmark = [
    pytest.mark.cuda,
    pytest.mark.skipif(not gsplat_available(), reason="needs a CUDA device and gsplat"),
]


@pytest.mark.parametrize("antialiased", [False, True])
def test_gsplat_matches_cpu_backend(antialiased):
    W, H = 96, 72
    scene = [t.float() for t in random_scene(500, W, H, cams=2, seed=0)]
    scene[3] = scene[3].clamp(max=0.9)  # below both alpha clamps (0.99 here, 0.999 in gsplat)
    outs, grads = {}, {}
    for backend, device in (("cpu", "cpu"), ("cuda", "cuda")):
        inputs = [t.to(device).clone().requires_grad_() for t in scene[:6]]
        out = render(
            *inputs, scene[6].to(device), W, H, sh_degree=3, antialiased=antialiased, backend=backend
        )
        (out.rgb.sum() + out.alpha.sum()).backward()
        outs[backend] = [t.detach().cpu() for t in (out.rgb, out.alpha, out.depth)]
        grads[backend] = [t.grad.cpu() for t in inputs]
        assert out.radii.shape == (2, 500)
    for a, b in zip(outs["cpu"], outs["cuda"], strict=True):
        assert float((a - b).abs().mean()) < 2e-3
    for a, b in zip(grads["cpu"], grads["cuda"], strict=True):
        cos = torch.nn.functional.cosine_similarity(a.flatten(), b.flatten(), dim=0)
        assert float(cos) > 0.99


def test_auto_backend_picks_gsplat_for_cuda_tensors():
    scene = [t.float().cuda() for t in random_scene(50, 32, 32, seed=1)]
    out = render(*scene, 32, 32, sh_degree=3)  # backend="auto"
    assert out.rgb.is_cuda and out.means2d.shape == (1, 50, 2)
