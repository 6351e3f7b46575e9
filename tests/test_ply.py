"""INRIA .ply export: layout (62 float properties, channel-major f_rest) and an exact round trip."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from go_core.errors import GoError
from go_core.gaussians import Gaussians
from go_core.ply import load_ply, ply_property_names, save_ply

pytestmark = pytest.mark.usefixtures("single_thread")  # small tensors: one thread is faster


def _random_gaussians(n=50, degree=2, seed=0) -> Gaussians:
    g = torch.Generator().manual_seed(seed)
    k = (degree + 1) ** 2
    return Gaussians(
        torch.randn(n, 3, generator=g),
        torch.randn(n, 4, generator=g),
        torch.randn(n, 3, generator=g) - 3,
        torch.randn(n, generator=g),
        torch.randn(n, k, 3, generator=g),
    )


def test_header_and_layout(tmp_path):
    g = _random_gaussians()
    path = save_ply(g, tmp_path / "p.ply")
    raw = path.read_bytes()
    header = raw[: raw.index(b"end_header\n") + len(b"end_header\n")].decode()
    props = [line.split()[-1] for line in header.splitlines() if line.startswith("property")]
    assert props == ply_property_names(3) and len(props) == 62
    assert "format binary_little_endian 1.0" in header and "element vertex 50" in header
    rows = np.frombuffer(raw[len(header) :], dtype="<f4").reshape(50, 62)
    col = {name: i for i, name in enumerate(props)}
    assert np.array_equal(rows[:, col["x"]], g.means[:, 0].numpy())
    assert np.array_equal(rows[:, col["opacity"]], g.opacity_logits.numpy())  # logit, as stored
    assert np.array_equal(rows[:, col["scale_1"]], g.log_scales[:, 1].numpy())  # log scale
    assert np.array_equal(rows[:, col["rot_0"]], g.quats[:, 0].numpy())  # w first
    # channel-major f_rest: f_rest_{c*15 + j} = sh[:, 1 + j, c]; degree 2 has 8 rest coefficients per channel
    assert np.array_equal(rows[:, col["f_rest_0"]], g.sh[:, 1, 0].numpy())
    assert np.array_equal(rows[:, col["f_rest_15"]], g.sh[:, 1, 1].numpy())
    assert np.array_equal(rows[:, col["f_rest_37"]], g.sh[:, 8, 2].numpy())
    assert np.all(rows[:, col["f_rest_8"] : col["f_rest_14"] + 1] == 0)  # padding of channel 0
    assert np.all(rows[:, col["nx"] : col["nz"] + 1] == 0)


@pytest.mark.parametrize("degree", [0, 2, 3])
def test_round_trip_is_exact(tmp_path, degree):
    g = _random_gaussians(degree=degree, seed=degree)
    back = load_ply(save_ply(g, tmp_path / "g.ply"), sh_degree=degree)
    for name, t in g.tensors().items():
        assert torch.equal(getattr(back, name), t), name
    padded = load_ply(tmp_path / "g.ply")
    assert padded.sh_degree == 3


def test_bad_files_raise_one_line_errors(tmp_path):
    bad = tmp_path / "bad.ply"
    bad.write_bytes(b"not a ply")
    with pytest.raises(GoError, match="not a .ply"):
        load_ply(bad)
    ascii_ply = tmp_path / "ascii.ply"
    ascii_ply.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nend_header\n")
    with pytest.raises(GoError, match="binary_little_endian"):
        load_ply(ascii_ply)
