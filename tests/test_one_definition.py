"""One definition for each operation that used to be written several times (uint8 rounding, compositing on
white, thumbnails, quaternion → rotation, ray–box, silhouette coverage), and the one rounding rule."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import numpy as np
import torch

from go_core.io.images import composite, thumbnail, to_uint8

REPO = Path(__file__).resolve().parents[1]
SOURCES = sorted(p for d in ("go_core", "steps", "go_pipeline") for p in (REPO / d).rglob("*.py"))


def _definitions(name: str) -> list[str]:
    return [
        f"{p.relative_to(REPO)}:{n.lineno}"
        for p in SOURCES
        for n in ast.walk(ast.parse(p.read_text()))
        if isinstance(n, ast.FunctionDef) and n.name == name
    ]


def test_each_operation_is_defined_once():
    for name in ("to_uint8", "composite", "thumbnail", "quat_to_rotmat", "ray_box", "ray_coverage"):
        assert len(_definitions(name)) == 1, (name, _definitions(name))
    assert _definitions("_thumb") == [] and _definitions("thumb") == []


def test_no_inline_uint8_rounding():
    inline = re.compile(r"\*\s*255(\.0)?\s*\+\s*0\.5|np\.round\([^)]*255")
    found = [
        f"{p.relative_to(REPO)}:{i}"
        for p in SOURCES
        if p.name != "images.py"
        for i, line in enumerate(p.read_text().splitlines(), 1)
        if inline.search(line) and "exact multiples" not in line and "np.float32(255.0))" not in line
    ]
    assert found == []


def test_rounding_rule_is_half_up_and_clipped():
    x = np.array([-0.2, 0.0, 0.5, 127.5 / 255, 0.2 / 255, 0.7 / 255, 1.0, 1.7], np.float32)
    expect = np.floor(np.clip(x, 0, 1) * np.float32(255) + np.float32(0.5)).astype(np.uint8)
    assert to_uint8(x).tolist() == expect.tolist() == [0, 0, 128, 128, 0, 1, 255, 255]
    assert to_uint8(torch.from_numpy(x)).tolist() == expect.tolist()
    u8 = np.arange(256, dtype=np.uint8)
    assert to_uint8(u8) is u8 and np.array_equal(to_uint8(u8 / np.float32(255)), u8)  # round trip


def test_composite_numpy_and_torch_agree():
    rng = np.random.default_rng(0)
    img, mask = rng.random((4, 5, 3), dtype=np.float32), rng.random((4, 5), dtype=np.float32)
    a = composite(img, mask)
    b = composite(torch.from_numpy(img), torch.from_numpy(mask)).numpy()
    assert a.dtype == np.float32 and np.array_equal(a, b)
    assert np.allclose(a, img * mask[..., None] + (1 - mask[..., None]))
    assert np.array_equal(composite(img, None), img)


def test_thumbnail_keeps_aspect_and_never_enlarges():
    img = np.zeros((40, 80, 3), np.float32)
    assert thumbnail(img, 20).shape == (10, 20, 3) and thumbnail(img, 200).shape == (40, 80, 3)
