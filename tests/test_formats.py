"""Compressed export formats (go_core.formats): the layouts, and a round trip through an independent reader
(npm spz-js, run by node: `cd js && npm ci`; those tests skip with a reason where it is absent)."""

from __future__ import annotations

import gzip
import struct

import _spz_reader as roundtrip
import numpy as np
import pytest
import torch

from go_core.camera import Camera
from go_core.formats import FILE_NAMES, encode
from go_core.formats.compressed_ply import CHUNK, morton_order
from go_core.formats.splat import decode_splat
from go_core.formats.spz import COLOR_SCALE, MAGIC, position_step
from go_core.gaussians import SH_C0, Gaussians
from go_core.render.synthetic import random_scene

needs_reader = pytest.mark.skipif(
    roundtrip.reader_missing() is not None, reason=str(roundtrip.reader_missing())
)


def _model(n: int = 1500, seed: int = 3) -> tuple[Gaussians, list[Camera]]:
    means, quats, scales, opac, sh, vms, ks = random_scene(n, 96, 80, cams=2, sh_degree=3, seed=seed)
    g = Gaussians(
        means=means.float(),
        quats=quats.float(),
        log_scales=scales.log().float(),
        opacity_logits=torch.logit(opac.clamp(1e-3, 1 - 1e-3)).float(),
        sh=torch.cat([sh[:, :1], sh[:, 1:].clamp(-0.95, 0.95)], 1).float(),  # .spz's SH range is [-1, 1]
    )
    cams = [Camera(f"c{i}", 96, 80, ks[i].numpy(), vms[i].numpy()) for i in range(len(vms))]
    return g, cams


def test_spz_header_and_sizes_follow_the_spec():
    g, _ = _model(300)
    raw = gzip.decompress(encode(g, "spz"))
    magic, version, n, degree, bits, flags, reserved = struct.unpack("<IIIBBBB", raw[:16])
    assert (magic, version, n, degree, bits, flags, reserved) == (MAGIC, 2, 300, 3, 12, 0, 0)
    # positions 9, alpha 1, colour 3, scale 3, rotation 3, SH 45 bytes a Gaussian
    assert len(raw) == 16 + 300 * (9 + 1 + 3 + 3 + 3 + 45)
    colours = np.frombuffer(raw[16 + 300 * 10 : 16 + 300 * 13], np.uint8).reshape(300, 3)
    expected = np.clip(np.round(g.sh[:, 0].double().numpy() * COLOR_SCALE * 255 + 127.5), 0, 255)
    assert np.array_equal(colours, expected.astype(np.uint8))


def test_spz_is_deterministic():
    g, _ = _model(200)
    assert encode(g, "spz") == encode(g, "spz")


def test_splat_layout_rows_hold_the_model():
    g, _ = _model(400)
    rows = decode_splat(encode(g, "splat"))
    assert len(rows) == 400
    order = roundtrip.match_order(g, _gaussians_from_splat(rows))
    assert np.allclose(rows["position"], g.means[order].numpy(), atol=0)
    assert np.allclose(rows["scale"], g.scales()[order].numpy(), rtol=1e-6)
    rgb = (0.5 + SH_C0 * g.sh[order, 0].double().numpy()) * 255
    assert np.abs(rows["rgba"][:, :3] - np.clip(rgb, 0, 255)).max() <= 0.5 + 1e-6
    assert np.abs(rows["rgba"][:, 3] - g.opacities()[order].double().numpy() * 255).max() <= 0.5 + 1e-6
    size = (g.scales()[order].double().prod(1) * g.opacities()[order].double()).numpy()
    assert np.all(np.diff(size) <= 1e-6 * size.max())  # largest first, as the format's converter


def _gaussians_from_splat(rows) -> Gaussians:
    n = len(rows)
    return Gaussians(
        means=torch.from_numpy(rows["position"].copy()),
        quats=torch.from_numpy((rows["rot"].astype(np.float32) - 128) / 128),
        log_scales=torch.from_numpy(np.log(rows["scale"])),
        opacity_logits=torch.zeros(n),
        sh=torch.zeros(n, 1, 3),
    )


def test_morton_order_keeps_chunks_compact():
    pts = np.random.default_rng(0).uniform(-1, 1, (CHUNK * 16, 3))
    order = morton_order(pts)
    assert sorted(order.tolist()) == list(range(len(pts)))
    extent = lambda p: (p.reshape(16, CHUNK, 3).max(1) - p.reshape(16, CHUNK, 3).min(1)).mean()  # noqa: E731
    assert extent(pts[order]) < 0.6 * extent(pts)


def _round_trip(tmp_path, fmt: str):
    """The model, its cameras, what spz-js reads back from its ``fmt`` file, and the attribute errors."""
    g, cams = _model()
    path = tmp_path / FILE_NAMES[fmt]
    path.write_bytes(encode(g, fmt))
    back = roundtrip.read_back(path)
    return g, cams, back, roundtrip.attribute_errors(g, back, roundtrip.written_order(g, fmt))


def _render_psnr(g, back, cams) -> float:
    bg = torch.ones(3)
    return roundtrip.compare(roundtrip.renders(back, cams, bg), roundtrip.renders(g, cams, bg), [None] * 2)[
        "psnr"
    ]


@needs_reader
def test_spz_read_by_spz_js_round_trips_within_the_quantisation(tmp_path):
    g, cams, back, err = _round_trip(tmp_path, "spz")
    assert len(back) == len(g) and back.sh_degree == 3
    assert err["position"]["max"] <= position_step() / 2 + 1e-6
    assert err["log_scale"]["max"] <= 1 / 32 + 1e-6
    assert err["opacity"]["max"] <= 1 / 255 + 1e-6
    assert err["sh_dc"]["max"] <= 0.5 / (COLOR_SCALE * 255) + 1e-6
    assert err["quat_xyz"]["max"] <= 1 / 127.5  # 8 bits of x, y, z (w >= 0), the reader renormalises
    assert err["rotation_deg"]["mean"] < 1.5  # 1.08 deg here: w = sqrt(1 - |xyz|²) is coarse near w = 0
    assert err["sh_rest"]["max"] <= 8.5 / 128 + 1e-6  # 1/128 steps, then degree >= 2 on a 16/128 grid
    assert _render_psnr(g, back, cams) > 35.0


@needs_reader
def test_compressed_ply_read_by_spz_js_round_trips(tmp_path):
    g, cams, back, err = _round_trip(tmp_path, "compressed_ply")
    assert len(back) == len(g)
    extent = (g.means.max(0).values - g.means.min(0).values).max().item()
    assert err["position"]["max"] <= extent / (2 * 1023) + 1e-6  # 10-11 bits within a chunk's bounds
    assert err["opacity"]["max"] <= 0.5 / 255 + 1e-6
    assert err["rotation_deg"]["max"] < 0.5  # smallest three, 10 bits each
    assert _render_psnr(g, back, cams) > 35.0
