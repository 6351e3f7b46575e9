"""The repair corpus (issue 34): geometry-based exclusion of reserved objects and their copies, the split, the
views, and one object made end to end (Blender render -> coarse stage -> pairs) on a tiny mesh."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from go_core.io.npz import write_npz_deterministic
from go_pipeline.pipeline import PipelineError
from tests._benchmark_module import benchmark_module, corpus_module

# the corpus package lives beside the prior's scripts (benchmarks/prior/corpus/), outside the package
_exclusion, _geometry, _split, _views = map(corpus_module, ("exclusion", "geometry", "split", "views"))
Shape, judge = _exclusion.Shape, _exclusion.judge
Mesh, read_obj, shape_distance = _geometry.Mesh, _geometry.read_obj, _geometry.shape_distance
geometry_groups, split_groups = _split.geometry_groups, _split.split_groups
NOVEL_ELEVATION, TRAIN_ELEVATION = _views.NOVEL_ELEVATION, _views.TRAIN_ELEVATION
draw_views = _views.draw_views

BPY_PYTHON = Path(os.environ.get("GO_BPY_PYTHON", Path.home() / ".venvs" / "bpy" / "bin" / "python"))


def _blob(n_lat: int = 24, n_lon: int = 32, bumps: float = 0.25) -> Mesh:
    """A lumpy, asymmetric closed surface (a UV sphere with a fixed radial relief), [N, 3] + triangles."""
    lat = np.linspace(0.0, np.pi, n_lat)
    lon = np.linspace(0.0, 2 * np.pi, n_lon, endpoint=False)
    t, p = np.meshgrid(lat, lon, indexing="ij")
    r = 1.0 + bumps * np.sin(3 * t) * np.cos(2 * p) + 0.5 * bumps * np.cos(5 * p + t)
    v = np.stack([r * np.sin(t) * np.cos(p) * 1.6, r * np.sin(t) * np.sin(p), r * np.cos(t) * 0.8], -1)
    v = v.reshape(-1, 3)
    faces = []
    for i in range(n_lat - 1):
        for j in range(n_lon):
            a, b = i * n_lon + j, i * n_lon + (j + 1) % n_lon
            c, d = a + n_lon, b + n_lon
            faces += [(a, c, b), (b, c, d)]
    return Mesh(v, np.asarray(faces, np.int64))


def _box(sx: float, sy: float, sz: float) -> Mesh:
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float64)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    tris = [(q[0], q[k], q[k + 1]) for q in quads for k in (1, 2)]
    return Mesh(corners * [sx, sy, sz], np.asarray(tris, np.int64))


def _write_obj(path: Path, mesh: Mesh, texture: bool = False) -> Path:
    """An OBJ (with an .mtl and a small checker texture when ``texture``) of ``mesh``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    lines = []
    if texture:
        from PIL import Image

        checker = (np.indices((16, 16)).sum(0) % 2).astype(np.uint8)
        img = np.stack([checker * 200 + 30, 90 + checker * 60, 200 - checker * 150], -1).astype(np.uint8)
        Image.fromarray(img).resize((64, 64), Image.NEAREST).save(path.parent / "tex.png")
        (path.parent / "m.mtl").write_text("newmtl m\nKd 1 1 1\nmap_Kd tex.png\n")
        lines += ["mtllib m.mtl", "usemtl m"]
    v = mesh.vertices
    lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in v]
    if texture:  # spherical UVs
        u = 0.5 + np.arctan2(v[:, 1], v[:, 0]) / (2 * np.pi)
        w = 0.5 + np.arcsin(np.clip(v[:, 2] / np.linalg.norm(v, axis=1), -1, 1)) / np.pi
        lines += [f"vt {a:.5f} {b:.5f}" for a, b in zip(u, w, strict=True)]
        lines += [f"f {a + 1}/{a + 1} {b + 1}/{b + 1} {c + 1}/{c + 1}" for a, b, c in mesh.faces]
    else:
        lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in mesh.faces]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_read_obj_round_trips_and_triangulates(tmp_path):
    mesh = _blob(6, 8)
    back = read_obj(_write_obj(tmp_path / "a.obj", mesh, texture=True))
    np.testing.assert_allclose(back.vertices, mesh.vertices, atol=1e-6)
    assert (back.faces == mesh.faces).all()
    (tmp_path / "q.obj").write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n")
    assert read_obj(tmp_path / "q.obj").faces.tolist() == [[0, 1, 2], [0, 2, 3]]


def test_exclusion_catches_recoloured_rescaled_and_remeshed_copies_of_a_reserved_mesh():
    reserved_mesh = _blob()
    reserved = [Shape.of("fam/milk", reserved_mesh), Shape.of("fam/plate", _box(1.0, 1.0, 0.1))]
    v = reserved_mesh.vertices
    copies = {
        "recoloured (same vertices)": Mesh(v.copy(), reserved_mesh.faces),
        "bigger (x1.7)": Mesh(v * 1.7 + [3.0, -2.0, 0.5], reserved_mesh.faces),
        "stretched per axis": Mesh(v * [1.25, 0.8, 1.1], reserved_mesh.faces),
        "Y-up copy (axes swapped)": Mesh(v[:, [0, 2, 1]] * 0.3, reserved_mesh.faces),
        "re-meshed (other vertex count), x2": Mesh(_blob(31, 45).vertices * 2.0, _blob(31, 45).faces),
    }
    for label, mesh in copies.items():
        verdict = judge(Shape.of(f"fam/{label}", mesh, seed=1), reserved)
        assert verdict["excluded"], (label, verdict)
        assert verdict["nearest"] == "fam/milk", (label, verdict)
    assert "same mesh" in judge(Shape.of("fam/red_milk", copies["bigger (x1.7)"]), reserved)["reason"]
    assert judge(Shape.of("fam/milk", reserved_mesh), reserved)["reason"] == "reserved object"


def test_exclusion_keeps_other_shapes_even_boxes_of_other_proportions():
    box = _box(1.0, 0.4, 1.5)  # 9 vertices (one unused): not the same mesh as an 8-vertex box stretched
    reserved = [
        Shape.of("fam/milk", _blob()),
        Shape.of("fam/cereal", Mesh(np.vstack([box.vertices, [0, 0, 0]]), box.faces)),
    ]
    other_blob = _blob(bumps=0.0)  # a smooth ellipsoid of the same proportions: a different shape
    for label, mesh in {"ellipsoid": other_blob, "flat box": _box(1.0, 1.0, 0.12)}.items():
        verdict = judge(Shape.of(f"fam/{label}", mesh), reserved)
        assert not verdict["excluded"], (label, verdict)
    # box normalisation alone would call these the same (every box is the unit cube): the proportions differ
    d, _ = shape_distance(Shape.of("a", _box(1.0, 1.0, 0.12)).points, reserved[1].points)
    assert d < 0.03


def test_split_keeps_copies_of_one_mesh_together():
    blob, box = _blob(), _box(1.0, 0.5, 2.0)
    shapes = [
        Shape.of("a/butter", blob),
        Shape.of("a/green_butter", Mesh(blob.vertices * 2, blob.faces), seed=3),
        Shape.of("a/box", box),
    ]
    groups = geometry_groups(shapes)
    assert groups == {"a/butter": "a/butter", "a/green_butter": "a/butter", "a/box": "a/box"}
    val = split_groups(sorted(set(groups.values())), seed=0, val_fraction=0.3)
    assert len(val) == 1 and val == split_groups(sorted(set(groups.values())), seed=0, val_fraction=0.3)


def test_views_are_seeded_and_in_their_ranges():
    a, b = draw_views(0, "x/obj", 24), draw_views(0, "x/obj", 24)
    assert a == b and a != draw_views(1, "x/obj", 24) and a != draw_views(0, "x/other", 24)
    assert len(a.train) == 4 and len(a.novel) == 24
    assert all(TRAIN_ELEVATION[0] <= el <= TRAIN_ELEVATION[1] for _, el in a.train)
    els = np.array([el for _, el in a.novel])
    assert NOVEL_ELEVATION[0] <= els.min() and els.max() <= NOVEL_ELEVATION[1]
    assert els.min() < 5.0 and els.max() > 45.0  # stratified: the novel views reach below and above
    azs = np.sort([az for az, _ in a.train])
    gaps = np.diff(np.append(azs, azs[0] + 360.0))
    assert np.all(np.abs(gaps - 90.0) < 13.0)


def _check_mesh_world(folder: Path) -> None:
    """The object's ``scene/mesh_world.npz`` is its normalised mesh in the cameras' frame (its silhouettes
    are the rendered masks), and ``--add-meshes`` writes the same one into a folder that lacks it."""
    from go_core.mesh.files import read_mesh_npz
    from go_core.metrics.geometry import silhouette_iou
    from go_core.scene.loader import load_scene

    path = folder / "scene" / "mesh_world.npz"
    truth = read_mesh_npz(path)
    assert np.linalg.norm(truth.vertices, axis=1).max() == pytest.approx(1.0, abs=1e-5)
    scene = load_scene(folder / "scene")
    assert min(silhouette_iou(truth, v.camera, v.mask) for v in scene.train) > 0.9
    path.unlink()
    corpus = benchmark_module("prior/repair_corpus")
    assert (
        corpus.main(["--out", str(folder.parents[1]), "--add-meshes", "--bpy-python", str(BPY_PYTHON)]) == 0
    )
    again = read_mesh_npz(path)
    assert np.array_equal(again.vertices, truth.vertices) and np.array_equal(again.faces, truth.faces)


@pytest.mark.skipif(
    not BPY_PYTHON.exists(), reason=f"no Python with the bpy wheel at {BPY_PYTHON} (GO_BPY_PYTHON)"
)
def test_corpus_makes_one_object_end_to_end(tmp_path):
    corpus = benchmark_module("prior/repair_corpus")
    assets = tmp_path / "assets"
    _write_obj(assets / "fam" / "blob" / "blob.obj", _blob(12, 16), texture=True)
    out = tmp_path / "corpus"
    args = corpus.parse_args(
        [
            "--out",
            str(out),
            "--assets",
            str(assets),
            "--bpy-python",
            str(BPY_PYTHON),
            "--res",
            "48",
            "--samples",
            "4",
            "--novel",
            "3",
            "--profile",
            "test",
        ]
    )
    entry = {"name": "fam/blob", "split": "train", "up": "Z", "meshes": ["fam/blob/blob.obj"]}
    info = corpus.make_object(entry, assets, args)
    folder = out / "objects" / "fam__blob"
    with np.load(folder / "pairs.npz") as data:
        arrays = {k: data[k] for k in data.files}
    assert arrays["novel_coarse_rgb"].shape == (3, 48, 48, 3) and arrays["novel_rgba"].shape == (3, 48, 48, 4)
    assert arrays["train_rgba"].shape == (4, 48, 48, 4) and arrays["novel_coarse_depth"].dtype == np.float16
    assert arrays["train_coarse_depth"].shape == (4, 48, 48)
    # a pairs.npz made before the training views' depth was stored gets the same depth added
    write_npz_deterministic(
        folder / "pairs.npz", {k: v for k, v in arrays.items() if k != "train_coarse_depth"}
    )
    assert corpus.add_train_depth(out) == 0
    with np.load(folder / "pairs.npz") as data:
        assert np.array_equal(data["train_coarse_depth"], arrays["train_coarse_depth"])
    alpha = arrays["novel_rgba"][..., 3]
    assert 0.05 < (alpha > 127).mean() < 0.9  # the object is in view and not filling it
    coarse_alpha = arrays["novel_coarse_alpha"] > 127
    iou = (coarse_alpha & (alpha > 127)).sum() / max((coarse_alpha | (alpha > 127)).sum(), 1)
    assert iou > 0.3 and info["novel_silhouette_iou_mean"] > 0.3
    transforms = json.loads((folder / "scene" / "transforms_test.json").read_text())
    np.testing.assert_allclose(
        arrays["novel_c2w"], [f["transform_matrix"] for f in transforms["frames"]], atol=1e-5
    )
    assert (
        not (folder / "work").exists()
        and json.loads((folder / "object.json").read_text())["novel_pairs"] == 3
    )
    _check_mesh_world(folder)
    shutil.rmtree(folder / "scene")  # the renders are redone from the same job: same images
    assert corpus.make_object(entry, assets, args)["novel_psnr"] == info["novel_psnr"]


def test_extend_index_keeps_old_splits_and_puts_a_new_copy_beside_its_group():
    """A larger asset tree's index adds only the objects the old index lacks; the old entries are kept as
    they are even where the fresh index drew another split, and a new object in an old object's geometry
    group takes that object's split (no near-copy across train and val)."""
    corpus = benchmark_module("prior/repair_corpus")

    def entry(name, group, split, excluded=False):
        return {"name": name, "excluded": excluded, "group": group, "split": split}

    kept = [entry("a/x", "g1", "val"), entry("a/y", "g2", "train"), entry("a/bad", None, None, True)]
    old = {"seed": 0, "val_fraction": 0.15, "objects": kept}
    new = [entry("b/copy_of_x", "g1", "train"), entry("b/new", "g9", "val"), entry("b/res", None, None, True)]
    redrawn = [entry("a/x", "g1", "train"), entry("a/y", "g2", "train"), entry("a/bad", None, None, True)]
    fresh = {"objects": redrawn + new}
    out = corpus.extend_index(old, fresh)
    assert out["objects"][:3] == old["objects"]
    added = {e["name"]: e for e in out["objects"][3:]}
    assert list(added) == ["b/copy_of_x", "b/new", "b/res"]
    assert added["b/copy_of_x"]["split"] == "val"  # beside a/x, not the fresh draw's "train"
    assert added["b/new"]["split"] == "val" and added["b/res"]["excluded"]
    assert out["seed"] == 0 and out["val_fraction"] == 0.15


def test_corpus_set_values_become_the_runners_overrides():
    """``--set STEP.PARAM=VALUE`` reaches the coarse stage as the runner's overrides, each value read as YAML
    (so the runner's type check sees numbers and booleans, not strings); an item without "=" is refused."""
    corpus = benchmark_module("prior/repair_corpus")
    args = corpus.parse_args(
        ["--out", "x", "--set", "coarse.lambda_anisotropy=0", "--set", "coarse.floaters=false"]
    )
    assert args.overrides == {"coarse.lambda_anisotropy": 0, "coarse.floaters": False}
    assert corpus.parse_args(["--out", "x"]).overrides == {}
    with pytest.raises(PipelineError, match="STEP.PARAM=VALUE"):
        corpus.parse_args(["--out", "x", "--set", "coarse.lambda_anisotropy"])
