"""The run report as a browser shows it: headless Chromium (Debian's `chromium`) renders the report.html of
the built-in example (test profile); the screenshot shows its images, and its interactive 3D viewer, put
on a test camera, draws what go-pipeline's own rasterizer draws from it (tests/_browser.py)."""

from __future__ import annotations

import _browser as shot
import numpy as np
import pytest
import torch

needs_chromium = pytest.mark.skipif(
    shot.find_chromium() is None, reason="needs chromium (Debian: apt-get install chromium)"
)
VIEWER_MIN_PSNR = 25.0  # dB on the object's pixels (issue 36)


@pytest.fixture(scope="module")
def example(tmp_path_factory):
    from go_pipeline.cli import main

    work = tmp_path_factory.mktemp("ex")
    assert main(["run", "--example", "--workdir", str(work), "--profile", "test", "--quiet"]) == 0
    return work / "basket"


@pytest.mark.slow
@needs_chromium
def test_report_html_renders_in_headless_chromium(example, tmp_path):
    html = example / ".go" / "outputs" / "report.html"
    text = html.read_text()
    assert "Test views" in text and "mean |RGB error|" in text  # the grid's colour bar is HTML
    assert text.count("data:image/png;base64,") >= 4 and "data:image/gif;base64," in text  # + contact sheet
    png = shot.screenshot(html, tmp_path / "report.png")
    facts = shot.check_screenshot(png)
    assert (facts["width"], facts["height"]) == (1200, 2400)
    assert facts["non_white_fraction"] > 0.05  # text, tables and images, not a blank page
    assert facts["colourful_fraction"] > 0.005  # the error maps and plots were drawn


@pytest.mark.slow
@needs_chromium
def test_report_viewer_matches_the_rasterizer_on_a_test_camera(example, tmp_path):
    from PIL import Image

    from go_core import artifacts as art
    from go_core.ply import load_ply
    from go_core.render import render_camera
    from go_pipeline import store

    html = example / ".go" / "outputs" / "report.html"
    assert html.stat().st_size < 15e6  # a typical report stays small enough to mail
    wd = example / ".go"
    _, test = art.read_scene_cameras(store.artifact_dir(wd, "scene"))
    g = load_ply(example / ".go" / "outputs" / "model.ply")
    index = len(test) // 2
    out = render_camera(g, test[index], background=torch.ones(3))
    ours = out.rgb[0].clamp(0, 1).double().numpy()
    obj = out.alpha[0, ..., 0].numpy() > 0.5  # the object's pixels, as the rasterizer draws them
    viewer = shot.viewer_shot(html, "test", index).astype(np.float64) / 255.0
    Image.fromarray(np.concatenate([(ours * 255).round().astype(np.uint8), viewer_u8(viewer)], 1)).save(
        tmp_path / "viewer_vs_rasterizer.png"
    )
    assert viewer.shape == ours.shape
    assert obj.mean() > 0.02  # the camera sees the object
    psnr = -10 * np.log10(((viewer - ours) ** 2).mean(-1)[obj].mean())
    assert psnr >= VIEWER_MIN_PSNR, f"viewer vs rasterizer on the object's pixels: {psnr:.2f} dB"


def viewer_u8(img: np.ndarray) -> np.ndarray:
    return (img * 255).round().astype(np.uint8)


MESH_MIN_IOU = 0.95  # vs go-pipeline's own silhouette of model_mesh.ply: 0.981 measured (test view 4)
MESH_MAX_COLOUR_ERROR = 0.04  # mean |RGB| vs the splat render: 0.017 measured; 0.06-0.10 gamma-doubled


@pytest.mark.slow
@needs_chromium
def test_report_viewer_mesh_tab_draws_the_mesh_on_a_test_camera(example, tmp_path):
    """The mesh tab shows the mesh step's model_mesh.ply where go-pipeline's OpenCV polygon fill puts it
    (same camera), in its vertex colours (sRGB, not gamma-shifted: compared with the splat render)."""
    from PIL import Image

    from go_core import artifacts as art
    from go_core.mesh.files import read_ply
    from go_core.metrics.geometry import silhouette
    from go_core.ply import load_ply
    from go_core.render import render_camera
    from go_pipeline import store

    outputs = example / ".go" / "outputs"
    _, test = art.read_scene_cameras(store.artifact_dir(example / ".go", "scene"))
    index = len(test) // 2
    sil = silhouette(read_ply(outputs / "model_mesh.ply"), test[index])
    shown = shot.viewer_shot(outputs / "report.html", "test", index, view="mesh", clear="#ff00ff")
    Image.fromarray(shown).save(tmp_path / "viewer_mesh.png")
    rgb = shown.astype(np.float64) / 255.0
    drawn = np.abs(rgb - [1.0, 0.0, 1.0]).max(-1) > 0.2  # anything but the magenta background
    assert shown.shape[:2] == sil.shape and sil.mean() > 0.02
    iou = (drawn & sil).sum() / (drawn | sil).sum()
    assert iou >= MESH_MIN_IOU, f"viewer's mesh vs go-pipeline's mesh silhouette: IoU {iou:.3f}"
    splats = render_camera(load_ply(outputs / "model.ply"), test[index], background=torch.ones(3))
    both = drawn & sil & (splats.alpha[0, ..., 0].numpy() > 0.99)
    error = np.abs(rgb - splats.rgb[0].clamp(0, 1).double().numpy())[both].mean(0)
    assert (error < MESH_MAX_COLOUR_ERROR).all(), f"mean |RGB| mesh (viewer) vs splats (rasterizer): {error}"
