"""The report viewer's data and HTML block: the mesh step's mesh goes in (gzip, base64, the file's own
bytes) with a mesh tab when the run has one, and nothing of it when the run has none; the vendored bundle
has the code that reads it. The browser side is checked in test_report_screenshot.py (slow)."""

from __future__ import annotations

import base64
import gzip
import json

import numpy as np
import pytest

from go_pipeline.reporting.viewer import mesh_record, viewer_bundle, viewer_html


@pytest.fixture
def mesh_ply(tmp_path):
    from go_core.mesh.files import write_ply
    from go_core.mesh.types import TriMesh

    verts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], np.float64)
    faces = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], np.int64)
    colours = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [0.5, 0.5, 0.5]], np.float32)
    return write_ply(TriMesh(verts, faces, colours), tmp_path / "model_mesh.ply")


def base_data() -> dict:
    cam = {"name": "r_0", "width": 8, "height": 6, "fx": 8.0, "fy": 8.0, "cx": 4.0, "cy": 3.0}
    cam |= {"R": np.eye(3).tolist(), "t": [0.0, 0.0, 4.0]}
    cameras = {"train": [cam], "test": []}
    return {"model": "", "center": [0, 0, 0], "cameras": cameras, "background": [1, 1, 1]}


def embedded(page: str) -> dict:
    start = page.index("id='go-viewer-data'>") + len("id='go-viewer-data'>")
    return json.loads(page[start : page.index("</script>", start)])


def test_mesh_goes_in_as_its_own_file_bytes_with_a_tab(mesh_ply):
    record = mesh_record(mesh_ply)
    assert gzip.decompress(base64.b64decode(record["mesh"])) == mesh_ply.read_bytes()
    assert record["mesh_counts"] == {"vertices": 4, "faces": 4}
    assert mesh_record(mesh_ply) == record  # no timestamp in the gzip: the same mesh, the same report
    page = viewer_html({**base_data(), "gaussians": 0, **record})
    assert embedded(page)["mesh"] == record["mesh"]
    assert "<button data-tab='mesh'>mesh (4 faces)</button>" in page and "data-tab='splats'" in page


def test_no_mesh_no_tab():
    page = viewer_html({**base_data(), "gaussians": 0})
    assert "class='go-viewer-tabs'" not in page and "data-tab=" not in page and "mesh" not in embedded(page)


def test_the_vendored_viewer_reads_the_mesh():
    code, info = viewer_bundle()
    # the tab switch, the gzip stream and three.js's PLY reader (binary little-endian, vertex colours)
    assert "showTab" in code and "go-viewer-tabs" in code and "DecompressionStream" in code
    assert "binary_little_endian" in code and "vertex_indices" in code
    assert info["bytes"] == len(code.encode("utf-8"))


def test_a_broken_mesh_file_is_refused(tmp_path):
    bad = tmp_path / "model_mesh.ply"
    bad.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 3\n")
    with pytest.raises(ValueError, match="model_mesh.ply: not a readable mesh"):
        mesh_record(bad)
