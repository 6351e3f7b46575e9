"""The report's interactive 3D viewer: the final model as splats in the browser, one self-contained block.

The block inlines the vendored viewer (three.js + Spark, MIT, built from exact npm versions by js/build.mjs
into go_pipeline/_resources/viewer/viewer.min.js) and the model as base64 ``.spz`` (Niantic's compressed
format, ~10x smaller than the ``.ply``), with the training and test cameras in go-pipeline's convention
(OpenCV world-to-camera, pixel centres at +0.5) so that a button puts the viewer on a scene camera with the
same projection as go-pipeline's rasterizer (fx, fy, cx, cy, near 0.01) on the render background.
"""

from __future__ import annotations

import base64
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


def viewer_data(model_ply: Path, scene_dir: Path, background=(1.0, 1.0, 1.0)) -> dict[str, Any]:
    """What the viewer needs: the model (base64 .spz), its centre, the cameras and the background."""
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
    }


def viewer_html(data: dict[str, Any]) -> str:
    """The viewer's HTML block: the data, the stage, camera buttons and the inlined script."""
    code, info = viewer_bundle()
    payload = json.dumps(data, separators=(",", ":")).replace("</", "<\\/")
    script = code.replace("</script", "<\\/script")
    versions = ", ".join(f"{k} {v}" for k, v in info["packages"].items() if k != "esbuild")
    return (
        f"<style>{VIEWER_CSS}</style><div id='go-viewer'><p class='go-viewer-label'>loading the model "
        f"({data['gaussians']} Gaussians)...</p><div class='go-viewer-stage'></div>"
        "<p>drag: orbit, wheel: zoom, right-drag: pan; cameras: <span class='go-viewer-buttons'></span></p>"
        f"<p class='go-viewer-note'>viewer: {versions} (MIT), vendored, SHA-256 {info['sha256'][:12]}</p>"
        f"</div><script type='application/json' id='go-viewer-data'>{payload}</script>"
        f"<script>{script}</script>"
    )
