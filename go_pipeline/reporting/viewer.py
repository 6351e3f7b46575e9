"""The report's interactive 3D viewer: the final model as splats in the browser, one self-contained block.

The block inlines the vendored viewer (three.js + Spark, MIT, built from exact npm versions by js/build.mjs
into go_pipeline/_resources/viewer/viewer.min.js) and the model as base64 ``.spz`` (Niantic's compressed
format, ~10x smaller than the ``.ply``), with the training and test cameras in go-pipeline's convention
(OpenCV world-to-camera, pixel centres at +0.5) so that a button puts the viewer on a scene camera with the
same projection as go-pipeline's rasterizer (fx, fy, cx, cy, near 0.01) on the render background. When the
run has a mesh (the mesh step's ``model_mesh.ply``, world frame like the model), it goes in too (gzip,
base64) and a "mesh" tab shows it from the same cameras; without one the block has no tab.
"""

from __future__ import annotations

import base64
import gzip
import hashlib
import json
from pathlib import Path
from typing import Any

import numpy as np

from go_pipeline.resources import viewer_bundle_dir

VIEWER_CSS = (
    "#go-viewer{border:1px solid #ccc;padding:.5em}.go-viewer-stage{margin:0;line-height:0}"
    ".go-viewer-canvas{display:block;touch-action:none;cursor:grab}"
    ".go-viewer-buttons button{margin:2px;font-size:80%}.go-viewer-label{color:#555;font-size:90%}"
    ".go-viewer-tabs button{margin:0 2px 4px 0}.go-viewer-tabs button.go-active{font-weight:bold}"
)


def viewer_bundle() -> tuple[str, dict[str, Any]]:
    """The vendored viewer script and its record (versions, SHA-256); the script must match the record."""
    folder = viewer_bundle_dir()
    info = json.loads((folder / "viewer.json").read_text())
    code = (folder / info["file"]).read_bytes()
    digest = hashlib.sha256(code).hexdigest()
    if digest != info["sha256"]:
        raise RuntimeError(f"{folder / info['file']}: SHA-256 {digest} is not the recorded {info['sha256']}")
    return code.decode("utf-8"), info


def camera_record(cam) -> dict[str, Any]:
    """One camera as the viewer reads it (OpenCV world-to-camera rotation and translation, intrinsics)."""
    k, w2c = np.asarray(cam.K, dtype=float), np.asarray(cam.world_to_cam, dtype=float)
    return {
        "name": str(cam.name),
        "width": int(cam.width),
        "height": int(cam.height),
        "fx": float(k[0, 0]),
        "fy": float(k[1, 1]),
        "cx": float(k[0, 2]),
        "cy": float(k[1, 2]),
        "R": w2c[:3, :3].tolist(),
        "t": w2c[:3, 3].tolist(),
    }


def mesh_record(mesh_ply: Path) -> dict[str, Any]:
    """The mesh step's ``model_mesh.ply`` for the viewer: the file itself, gzip (no timestamp: the same
    mesh gives the same bytes) and base64, with its counts; read once first so a broken file fails here."""
    from go_core.mesh.files import read_ply

    try:
        mesh = read_ply(mesh_ply)
    except Exception as exc:  # noqa: BLE001 - trimesh raises many kinds; one line naming the file
        raise ValueError(f"{mesh_ply}: not a readable mesh ({type(exc).__name__}: {exc})") from exc
    packed = gzip.compress(mesh_ply.read_bytes(), compresslevel=9, mtime=0)
    return {
        "mesh": base64.b64encode(packed).decode("ascii"),
        "mesh_counts": {"vertices": int(len(mesh.vertices)), "faces": int(len(mesh.faces))},
    }


def viewer_data(
    model_ply: Path, scene_dir: Path, background=(1.0, 1.0, 1.0), mesh_ply: Path | None = None
) -> dict[str, Any]:
    """What the viewer needs: the model (base64 .spz), its centre, the cameras and the background, and the
    mesh when the run has one (``mesh_ply``)."""
    from go_core import artifacts as art
    from go_core.formats.spz import encode_spz
    from go_core.ply import load_ply

    g = load_ply(model_ply)
    train, test = art.read_scene_cameras(scene_dir)
    return {
        "model": base64.b64encode(encode_spz(g)).decode("ascii"),
        "center": np.median(g.means.detach().cpu().numpy(), axis=0).tolist(),
        "cameras": {"train": [camera_record(c) for c in train], "test": [camera_record(c) for c in test]},
        "background": [float(x) for x in background],
        "gaussians": len(g),
        **(mesh_record(mesh_ply) if mesh_ply is not None else {}),
    }


def tabs_html(data: dict[str, Any]) -> str:
    """The splats / mesh / shaded-mesh tabs, only when the data holds a mesh."""
    if "mesh" not in data:
        return ""
    faces = data["mesh_counts"]["faces"]
    return (
        "<p class='go-viewer-tabs'><button data-tab='splats' class='go-active'>splats</button>"
        f"<button data-tab='mesh'>mesh ({faces} faces)</button><button data-tab='shaded'>mesh, shaded"
        "</button></p>"
    )


def viewer_html(data: dict[str, Any]) -> str:
    """The viewer's HTML block: the data, the stage, camera buttons and the inlined script."""
    code, info = viewer_bundle()
    payload = json.dumps(data, separators=(",", ":")).replace("</", "<\\/")
    script = code.replace("</script", "<\\/script")
    versions = ", ".join(f"{k} {v}" for k, v in info["packages"].items() if k != "esbuild")
    return (
        f"<style>{VIEWER_CSS}</style><div id='go-viewer'>{tabs_html(data)}<p class='go-viewer-label'>loading "
        f"the model ({data['gaussians']} Gaussians)...</p><div class='go-viewer-stage'></div>"
        "<p>drag: orbit, wheel: zoom, right-drag: pan; cameras: <span class='go-viewer-buttons'></span></p>"
        f"<p class='go-viewer-note'>viewer: {versions} (MIT), vendored, SHA-256 {info['sha256'][:12]}</p>"
        f"</div><script type='application/json' id='go-viewer-data'>{payload}</script>"
        f"<script>{script}</script>"
    )
