"""An independent reader of the compressed export formats for the round-trip tests: npm spz-js, run by
node (`cd js && npm ci`), reads a .spz or SuperSplat .compressed.ply back into Gaussians; the per-attribute
round-trip errors and render comparisons (go-pipeline's rasterizer). Also used by
benchmarks/archive/export_roundtrip.py."""

from __future__ import annotations

import json
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
READER = ROOT / "js" / "read_splats.mjs"


def reader_missing() -> str | None:
    """Why the independent reader cannot run here, or None."""
    if shutil.which("node") is None:
        return "needs node (Debian: apt-get install nodejs)"
    if not (ROOT / "js" / "node_modules" / "spz-js").is_dir():
        return "needs npm spz-js (cd js && npm ci)"
    return None


def read_back(path: Path):
    """The Gaussians that spz-js decodes from ``path`` (a .spz or a SuperSplat .compressed.ply)."""
    from go_core.gaussians import Gaussians

    with tempfile.TemporaryDirectory(prefix="go-readback-") as tmp:
        out = Path(tmp) / "cloud"
        subprocess.run(["node", str(READER), str(path), str(out)], check=True, capture_output=True)
        meta = json.loads(out.with_suffix(".json").read_text())
        flat = np.fromfile(out.with_suffix(".f32"), dtype="<f4")
    n, parts, at = meta["numPoints"], {}, 0
    for name, length in meta["lengths"].items():
        parts[name] = flat[at : at + length]
        at += length
    rest = parts["sh"].reshape(n, -1, 3)
    quats = parts["rotations"].reshape(n, 4)[:, [3, 0, 1, 2]]  # xyzw -> wxyz
    means = parts["positions"].reshape(n, 3)
    if path.suffix == ".spz":  # .spz holds RUB: back to go-pipeline's OpenCV (RDF) world
        from go_core.formats.spz import FLIP_YZ, SH_FLIP_YZ

        means, quats = means * FLIP_YZ, quats * np.array([1.0, 1.0, -1.0, -1.0])
        rest = rest * SH_FLIP_YZ[: rest.shape[1], None]
    sh = np.concatenate([parts["colors"].reshape(n, 1, 3), rest], axis=1).astype(np.float32)
    return Gaussians(
        means=torch.from_numpy(np.ascontiguousarray(means, dtype=np.float32)),
        quats=torch.from_numpy(np.ascontiguousarray(quats, dtype=np.float32)),
        log_scales=torch.from_numpy(parts["scales"].reshape(n, 3).copy()),
        opacity_logits=torch.from_numpy(parts["alphas"].copy()),
        sh=torch.from_numpy(np.ascontiguousarray(sh)),
    )


def match_order(original, decoded) -> torch.Tensor:
    """Index of each decoded Gaussian's original by nearest position (for a format that reorders)."""
    from scipy.spatial import cKDTree

    _, idx = cKDTree(original.means.double().numpy()).query(decoded.means.double().numpy())
    return torch.from_numpy(idx)


def written_order(original, fmt: str) -> torch.Tensor:
    """Index of each written Gaussian's original: .spz keeps the order, the compressed .ply writes along
    its Morton curve (go_core.formats.compressed_ply.morton_order)."""
    if fmt == "compressed_ply":
        from go_core.formats.compressed_ply import morton_order

        return torch.from_numpy(morton_order(original.means.double().numpy()))
    return torch.arange(len(original))


def attribute_errors(original, decoded, order: torch.Tensor | None = None) -> dict[str, dict[str, float]]:
    """Largest and mean absolute round-trip error per attribute (rotation: angle in degrees); ``order``:
    the original of each decoded Gaussian (default: by nearest position)."""
    order = match_order(original, decoded) if order is None else order
    o = original.select(order).with_sh_degree(decoded.sh_degree)
    qa, qb = o.normalized_quats().double(), decoded.normalized_quats().double()
    angle = torch.rad2deg(2 * torch.acos((qa * qb).sum(-1).abs().clamp(max=1.0)))
    sign = torch.where((qa * qb).sum(-1, keepdim=True) < 0, -1.0, 1.0).double()
    diffs = {
        "position": (decoded.means.double() - o.means.double()).abs(),
        "log_scale": (decoded.log_scales.double() - o.log_scales.double()).abs(),
        "rotation_deg": angle,
        "quat_xyz": (qb[:, 1:] * sign - qa[:, 1:]).abs(),
        "opacity": (decoded.opacities().double() - o.opacities().double()).abs(),
        "sh_dc": (decoded.sh[:, 0].double() - o.sh[:, 0].double()).abs(),
        "sh_rest": (decoded.sh[:, 1:].double() - o.sh[:, 1:].double()).abs(),
    }
    return {
        k: {"max": float(v.max()) if v.numel() else 0.0, "mean": float(v.mean()) if v.numel() else 0.0}
        for k, v in diffs.items()
    }


def renders(g, cameras, background) -> list[torch.Tensor]:
    """``g`` rendered by go-pipeline's rasterizer from each camera, float64 [H, W, 3] in [0, 1]."""
    from go_core.render import render_camera

    return [render_camera(g, cam, background=background).rgb[0].clamp(0, 1).double() for cam in cameras]


def psnr(a: torch.Tensor, b: torch.Tensor, where: torch.Tensor | None = None) -> float:
    """PSNR of two [H, W, 3] images in [0, 1], over the pixels ``where`` (default all)."""
    err = ((a - b) ** 2).mean(-1)
    return float(-10 * torch.log10(err[where].mean() if where is not None else err.mean()))


def compare(images: list[torch.Tensor], refs: list[torch.Tensor], masks: list[torch.Tensor]) -> dict:
    """Mean PSNR of ``images`` against ``refs``, over all pixels and over the object's (mask > 0.5)."""
    if any(m is None for m in masks):
        return {"psnr": float(np.mean([psnr(a, b) for a, b in zip(images, refs, strict=True)]))}
    return {
        "psnr": float(np.mean([psnr(a, b) for a, b in zip(images, refs, strict=True)])),
        "psnr_object": float(np.mean([psnr(a, b, m) for a, b, m in zip(images, refs, masks, strict=True)])),
    }
