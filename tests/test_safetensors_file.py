"""The safetensors writer is byte-reproducible and its files load with the library's own reader."""

from __future__ import annotations

import json
import struct
import subprocess
import sys

import numpy as np
import pytest
import torch
from safetensors import safe_open

from go_core.io.safetensors_file import safetensors_bytes, write_safetensors

META = {k: f"value {i}" for i, k in enumerate("hgfedcba")}  # several keys: the library's order varies


def _tensors() -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(3)
    return {
        "z.weight": torch.randn(4, 3, 3, 3, generator=g),
        "a.bias": torch.randn(5, generator=g).double(),
        "m.count": torch.arange(7, dtype=torch.int64),
    }


def test_same_input_same_bytes_within_a_process():
    blobs = {safetensors_bytes(_tensors(), META) for _ in range(20)}
    assert len(blobs) == 1


def test_same_bytes_across_processes(tmp_path):
    script = (
        "import sys, torch\n"
        "from go_core.io.safetensors_file import write_safetensors\n"
        "g = torch.Generator().manual_seed(3)\n"
        "t = {'z.weight': torch.randn(4, 3, 3, 3, generator=g),"
        " 'a.bias': torch.randn(5, generator=g).double(), 'm.count': torch.arange(7, dtype=torch.int64)}\n"
        f"write_safetensors(sys.argv[1], t, {META!r})\n"
    )
    outs = []
    for i in range(3):
        path = tmp_path / f"p{i}.safetensors"
        subprocess.run([sys.executable, "-c", script, str(path)], check=True)
        outs.append(path.read_bytes())
    write_safetensors(tmp_path / "here.safetensors", _tensors(), META)
    outs.append((tmp_path / "here.safetensors").read_bytes())
    assert len(set(outs)) == 1


@pytest.mark.parametrize("kind", ["torch", "numpy"])
def test_round_trip_with_the_library_reader(tmp_path, kind):
    tensors = _tensors() if kind == "torch" else {k: v.numpy() for k, v in _tensors().items()}
    path = write_safetensors(tmp_path / "t.safetensors", tensors, META)
    raw = path.read_bytes()
    (n,) = struct.unpack("<Q", raw[:8])
    assert (8 + n) % 8 == 0  # the format's header alignment
    header = json.loads(raw[8 : 8 + n])
    assert list(header) == ["__metadata__", "a.bias", "m.count", "z.weight"]
    assert list(header["__metadata__"]) == sorted(META)
    with safe_open(str(path), framework="pt") as f:
        assert f.metadata() == META
        for k, v in _tensors().items():
            got = f.get_tensor(k)
            assert got.dtype == v.dtype and torch.equal(got, v)


def test_no_metadata_and_numpy_scalars(tmp_path):
    path = write_safetensors(tmp_path / "n.safetensors", {"x": np.zeros((0, 3), np.float32)})
    with safe_open(str(path), framework="np") as f:
        assert f.metadata() is None or f.metadata() == {}
        assert f.get_tensor("x").shape == (0, 3)
