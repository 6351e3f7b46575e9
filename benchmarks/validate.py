"""Profiles on the validation set (issue 80): accuracy and CPU per object, paired differences, a plot.

Every scene of the set (``validation_set.py``: the rendered objects in ``--cache``, the dev and real scenes
in ``--shared``) runs under every ``--profile`` through the real runner, one work dir per scene shared by
the profiles (a step that two profiles run alike is computed once; each profile is charged the CPU seconds
of every step it uses, from the step's manifest, cached or not). A profile is ``NAME`` (a profile of
pipeline.yaml, or ``default``) or ``LABEL=NAME:step.param=value;step.param=value``. Scenes run as Ray
tasks (``--jobs`` at once, one thread each), or in this process with ``--jobs 1``. Each (scene, profile)
record is kept in ``--workroot/records``, so a call resumes, and a later call with more profiles reuses them.

Writes ``--out`` (JSON): per scene and profile, PSNR / SSIM / LPIPS* and the CPU and wall seconds of every
step; per profile, the means over the scenes that every profile finished; and every profile against the
first, paired: the mean difference of PSNR, LPIPS* and SSIM with a 95 % bootstrap interval, and the
median CPU ratio. Beside it, ``<out>.png``: CPU seconds against PSNR and LPIPS*, per scene and per profile;
and ``<out>.md``: the same figures as Markdown tables, for the docs.

    python benchmarks/validate.py --profile default --profile fast --cache ~/.cache/go-pipeline/validation \\
        --shared ../shared/data --workroot /tmp/validate --jobs 2 --out benchmarks/results/validate.json
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

BENCH = Path(__file__).resolve().parent
sys.path.insert(0, str(BENCH))
METRICS = ("psnr", "ssim", "lpips_star")
CPU_COLUMNS = ("cpu_s", "cpu_s_reconstruct")
BOOTSTRAP_SAMPLES = 10_000


@dataclass(frozen=True)
class Profile:
    """One point of the comparison: a pipeline.yaml profile (None: the defaults) and --set overrides."""

    label: str
    profile: str | None
    overrides: dict[str, Any] = field(default_factory=dict)

    def spec(self) -> dict[str, Any]:
        return {"profile": self.profile, "overrides": self.overrides}


def parse_profile(text: str) -> Profile:
    """``NAME`` or ``LABEL=NAME:step.param=value;step.param=value`` (values read as --set reads them)."""
    from go_pipeline.pipeline import parse_set_argument

    head, _, sets = text.partition(":")
    label, named, name = head.partition("=")
    name = name if named else label
    overrides = dict(parse_set_argument(item) for item in filter(None, sets.split(";")))
    name = name.strip()
    return Profile(label.strip(), None if name in ("", "default") else name, overrides)


def paired_bootstrap(diffs: np.ndarray, samples: int = BOOTSTRAP_SAMPLES, seed: int = 0) -> dict[str, float]:
    """Mean of paired differences with its 95 % percentile bootstrap interval (scenes resampled)."""
    diffs = np.asarray(diffs, dtype=np.float64)
    if diffs.size == 0:
        raise ValueError("no paired scene: nothing to compare")
    rng = np.random.default_rng(seed)
    means = diffs[rng.integers(0, diffs.size, size=(samples, diffs.size))].mean(axis=1)
    lo, hi = np.percentile(means, [2.5, 97.5])
    return {"mean": float(diffs.mean()), "ci95": [float(lo), float(hi)], "n": int(diffs.size)}


def step_times(summary) -> dict[str, dict[str, float | None]]:
    """CPU and wall seconds of every step the run used, from each step's manifest (its original run)."""
    from go_pipeline.store import read_manifest

    out = {}
    for step in summary.steps:
        manifest = read_manifest(step.artifact_dir) or {}
        out[step.name] = {
            "cpu_s": manifest.get("cpu_s"),
            "wall_s": manifest.get("wall_s"),
            "cached": step.cached,
            "resumed_from": (manifest.get("record") or {}).get("resumed_from") or 0,
        }
    return out


def resumed_steps(steps: dict[str, dict]) -> list[str]:
    """The steps whose artifact was finished by a resumed run: their manifest times count only the last
    attempt, so the profile's CPU seconds would be short (delete the artifact to measure it again)."""
    return [name for name, s in steps.items() if s.get("resumed_from")]


def run_one(scene: Path, workdir: Path, profile: Profile, seed: int, device: str = "auto") -> dict[str, Any]:
    """One scene under one profile: its eval metrics and step times, or the error that stopped it."""
    from go_pipeline.runner import run_pipeline

    t0 = time.perf_counter()
    try:
        summary = run_pipeline(
            scene,
            workdir=workdir,
            profile=profile.profile,
            overrides=profile.overrides,
            seed=seed,
            device=device,
            in_process=True,
            quiet=True,
        )
    except Exception as exc:  # noqa: BLE001 - a failing scene is a result of the profile, not a crash
        return {
            "status": "failed",
            "error": f"{type(exc).__name__}: {exc}",
            "wall_s": time.perf_counter() - t0,
        }
    metrics = json.loads((summary.step("eval").artifact_dir / "metrics.json").read_text())
    steps = step_times(summary)
    return {
        "status": "ok",
        **{k: metrics["mean"][k] for k in METRICS},
        "model": metrics.get("model"),
        "steps": steps,
        "cpu_s": round(sum(s["cpu_s"] or 0.0 for s in steps.values()), 2),
        "wall_s": round(sum(s["wall_s"] or 0.0 for s in steps.values()), 2),
        "run_wall_s": round(time.perf_counter() - t0, 2),
    }


def record_path(workroot: Path, scene: str, label: str) -> Path:
    return workroot / "records" / scene / f"{label}.json"


def kept_record(path: Path, key: dict, failed_too: bool = False) -> dict | None:
    """The kept result at ``path`` if it was made with the same key (spec, code, seed) and finished (or,
    with ``failed_too``, failed: a normal call runs a failed one again)."""
    if not path.exists():
        return None
    kept = json.loads(path.read_text())
    wanted = ("ok", "failed") if failed_too else ("ok",)
    return kept["result"] if kept.get("key") == key and kept["result"]["status"] in wanted else None


def run_scene(
    scene_name: str,
    scene: str,
    workroot: str,
    profiles: list[Profile],
    seed: int,
    code: str,
    kept_only: bool = False,
    device: str = "auto",
) -> dict:
    """Every profile on one scene, reusing a kept record of the same key; with ``kept_only``, running
    nothing (a profile without a kept record is reported as not run)."""
    out = {}
    for profile in profiles:
        path = record_path(Path(workroot), scene_name, profile.label)
        key = {
            "spec": profile.spec(),
            "code": code,
            "seed": seed,
            **({"device": device} if device != "auto" else {}),
        }
        kept = kept_record(path, key, failed_too=kept_only)
        if kept is not None or kept_only:
            out[profile.label] = kept or {"status": "not run", "error": "no kept record"}
            continue
        result = run_one(Path(scene), Path(workroot) / "work" / scene_name, profile, seed, device)
        result["threads"] = int(os.environ.get("OMP_NUM_THREADS", "0")) or None
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps({"key": key, "result": result}, indent=1))
        out[profile.label] = result
    return out


def run_all(scenes: dict[str, Path], args: argparse.Namespace, code: str) -> dict[str, dict]:
    """{scene: {label: result}}: on Ray with ``--jobs`` > 1 (one CPU and one thread per task), else here."""
    jobs = [
        (name, str(folder), str(args.workroot), args.profiles, args.seed, code, args.kept_only, args.device)
        for name, folder in scenes.items()
    ]
    if args.jobs <= 1 or args.kept_only:
        return {job[0]: run_scene(*job) for job in jobs}
    from go_pipeline.reporting.batch import import_ray

    ray = import_ray()
    ray.init(num_cpus=args.jobs, include_dashboard=False, log_to_driver=False)
    try:
        task = ray.remote(num_cpus=1, max_retries=1)(run_scene)
        refs = {job[0]: task.remote(*job) for job in jobs}
        return {name: ray.get(ref) for name, ref in refs.items()}
    finally:
        ray.shutdown()


def _columns(results: dict[str, dict], scenes: list[str], label: str) -> dict[str, np.ndarray]:
    """One profile's metrics and CPU seconds over ``scenes``: ``cpu_s`` (every step) and
    ``cpu_s_reconstruct`` (every step but eval, which only measures)."""
    rows = [results[s][label] for s in scenes]
    cols = {k: np.array([r[k] for r in rows], dtype=np.float64) for k in (*METRICS, "cpu_s")}
    evals = [((r.get("steps") or {}).get("eval") or {}).get("cpu_s") or 0.0 for r in rows]
    cols["cpu_s_reconstruct"] = cols["cpu_s"] - np.array(evals, dtype=np.float64)
    return cols


def _pairable(result: dict) -> bool:
    """Finished, with every step's CPU seconds whole (no step finished by a resumed run)."""
    return result.get("status") == "ok" and not resumed_steps(result.get("steps") or {})


def paired_table(results: dict[str, dict], labels: list[str]) -> dict[str, Any]:
    """Means over the scenes every profile finished, and each profile against the first (paired)."""
    paired = [s for s, r in results.items() if all(_pairable(r.get(label, {})) for label in labels)]
    if not paired:
        return {"paired_scenes": [], "means": {}, "against_first": {}}
    table = {label: _columns(results, paired, label) for label in labels}
    means = {label: {k: round(float(v.mean()), 4) for k, v in cols.items()} for label, cols in table.items()}
    for label in labels:
        for k in CPU_COLUMNS:
            means[label][f"{k}_median"] = round(float(np.median(table[label][k])), 1)
    base = labels[0]
    against = {}
    for label in labels[1:]:
        row = {k: paired_bootstrap(table[label][k] - table[base][k]) for k in METRICS}
        for k in CPU_COLUMNS:
            ratio = table[label][k] / table[base][k]
            row[f"{k}_ratio_median"] = round(float(np.median(ratio)), 4)
            row[f"{k}_ratio_range"] = [round(float(ratio.min()), 4), round(float(ratio.max()), 4)]
        against[label] = row
    return {"paired_scenes": paired, "means": means, "against_first": against}


def markdown(results: dict[str, dict], labels: list[str], table: dict) -> str:
    """The tables a doc quotes: per scene PSNR / LPIPS* / CPU s of every profile, then the means and each
    profile against the first (mean paired difference with its 95 % interval, median CPU ratio)."""
    head = "| scene | " + " | ".join(f"{label}: PSNR / LPIPS* / CPU s" for label in labels) + " |"
    lines = [head, "|---" * (len(labels) + 1) + "|"]
    for scene in table["paired_scenes"]:
        cells = [f"{results[scene][lb]['psnr']:.2f} / {results[scene][lb]['lpips_star']:.2f} / "
                 f"{results[scene][lb]['cpu_s']:.0f}" for lb in labels]  # fmt: skip
        lines.append(f"| {scene} | " + " | ".join(cells) + " |")
    means = [f"**{table['means'][lb]['psnr']:.2f} / {table['means'][lb]['lpips_star']:.2f} / "
             f"{table['means'][lb]['cpu_s']:.0f}**" for lb in labels]  # fmt: skip
    lines += ["| mean | " + " | ".join(means) + " |", ""]
    for label, row in table["against_first"].items():
        psnr, lp = row["psnr"], row["lpips_star"]
        lines.append(
            f"- {label} against {labels[0]} ({psnr['n']} scenes): PSNR {psnr['mean']:+.2f} dB "
            f"[{psnr['ci95'][0]:+.2f}, {psnr['ci95'][1]:+.2f}], LPIPS* {lp['mean']:+.2f} "
            f"[{lp['ci95'][0]:+.2f}, {lp['ci95'][1]:+.2f}], CPU x{row['cpu_s_ratio_median']:.2f} "
            f"(median; without eval x{row['cpu_s_reconstruct_ratio_median']:.2f})"
        )
    return "\n".join(lines) + "\n"


def plot(results: dict[str, dict], labels: list[str], table: dict, path: Path) -> None:
    """CPU seconds against PSNR and LPIPS*: each scene faint, each profile's mean bold."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for ax, metric, name in zip(
        axes, ("psnr", "lpips_star"), ("PSNR (dB)", "LPIPS* (x100, lower is better)"), strict=True
    ):
        for i, label in enumerate(labels):
            colour = f"C{i}"
            pts = [
                (r[label]["cpu_s"], r[label][metric])
                for r in results.values()
                if r.get(label, {}).get("status") == "ok"
            ]
            if pts:
                x, y = zip(*pts, strict=True)
                ax.scatter(x, y, s=10, alpha=0.35, color=colour)
            if label in table["means"]:
                m = table["means"][label]
                ax.scatter(
                    [m["cpu_s"]], [m[metric]], s=90, color=colour, edgecolor="k", label=label, zorder=3
                )
        ax.set_xscale("log")
        ax.set_xlabel("CPU seconds per scene (mean: large dots)")
        ax.set_ylabel(name)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(f"validation set: {len(table['paired_scenes'])} scenes every profile finished")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    from validation_set import DEFAULT_CACHE

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--profile", dest="profiles", action="append", required=True, type=parse_profile)
    ap.add_argument("--cache", type=Path, default=DEFAULT_CACHE, help="validation_set.py's renders")
    ap.add_argument("--shared", type=Path, default=None, help="../shared/data (dev and real scenes)")
    ap.add_argument("--kinds", nargs="*", default=["rendered", "dev", "real"], help="which scenes of the set")
    ap.add_argument("--scenes", nargs="*", default=None, help="only these scenes (short names)")
    ap.add_argument("--workroot", type=Path, required=True, help="work dirs and kept records")
    ap.add_argument("--jobs", type=int, default=1, help="scenes at once (Ray tasks, one thread each)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--code", default=None, help="read and write the records of this code version (default: HEAD)"
    )
    ap.add_argument("--device", choices=["auto", "cpu", "cuda"], default="auto", help="as go-pipeline run's")
    ap.add_argument("--note", default="", help="a note kept in the JSON (how the records were made)")
    ap.add_argument("--kept-only", action="store_true", help="run nothing: tabulate the kept records")
    ap.add_argument("--out", type=Path, required=True, help="the JSON; the plot goes beside it (.png)")
    args = ap.parse_args(argv)
    labels = [p.label for p in args.profiles]
    if len(set(labels)) != len(labels):
        ap.error(f"profile labels must differ: {labels}")
    return args


def select_scenes(args: argparse.Namespace) -> dict[str, Path]:
    from validation_set import kinds, load_manifest, scene_folders

    manifest = load_manifest()
    kind = kinds(manifest)
    found = scene_folders(args.cache.expanduser(), args.shared, manifest)
    order = args.scenes or list(found)  # --scenes also sets the order the scenes start in
    chosen = {n: found[n] for n in order if n in found and kind[n] in args.kinds}
    if not chosen:
        raise SystemExit(f"error: no scene of the validation set found in {args.cache} / {args.shared}")
    return chosen


def main(argv: list[str] | None = None) -> int:
    from _lib.machine import code_version, cpu_name

    args = parse_args(argv)
    scenes = select_scenes(args)
    labels = [p.label for p in args.profiles]
    code = args.code or code_version()
    t0 = time.perf_counter()
    results = run_all(scenes, args, code)
    table = paired_table(results, labels)
    out = {
        "command": "python benchmarks/validate.py " + " ".join(sys.argv[1:] if argv is None else argv),
        "code": code,
        "machine": cpu_name(),
        "cpu_count": os.cpu_count(),
        "jobs": args.jobs,
        "seed": args.seed,
        "profiles": {p.label: p.spec() for p in args.profiles},
        "wall_s": round(time.perf_counter() - t0, 1),
        "note": args.note,
        "scenes": results,
        **table,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(out, indent=1, sort_keys=True) + "\n")
    plot(results, labels, table, args.out.with_suffix(".png"))
    args.out.with_suffix(".md").write_text(markdown(results, labels, table))
    failed = [f"{s}/{label}" for s, r in results.items() for label, v in r.items() if v["status"] == "failed"]
    not_run = sum(v["status"] == "not run" for r in results.values() for v in r.values())
    resumed = [
        f"{s}/{label}"
        for s, r in results.items()
        for label, v in r.items()
        if resumed_steps(v.get("steps") or {})
    ]
    print(f"{len(table['paired_scenes'])} of {len(scenes)} scenes paired; failed: {failed or 'none'}", end="")
    print(f"; {not_run} results not run (no kept record)" if not_run else "")
    if resumed:
        print(f"not paired, a step finished by a resumed run (its CPU seconds are short): {resumed}")
    for label, m in table["means"].items():
        print(f"{label:16s} PSNR {m['psnr']:.2f}  LPIPS* {m['lpips_star']:.2f}  CPU s mean {m['cpu_s']:.0f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
