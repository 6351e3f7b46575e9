"""Speed against error: sweep pipeline settings, time each run, score it, plot the Pareto front.

Every combination of the ``--grid`` values (``step.param=v1,v2,...``, e.g. coarse iterations × resolution)
and of the ``--ablation`` override sets runs through the cache-aware runner in ONE work dir, so settings
that share upstream steps reuse their artifacts; a configuration's time is the sum of the wall seconds of
the artifacts it uses (original timings for reused ones), its error the eval step's mean LPIPS (vgg, the
paper's; alex when vgg weights are missing) and PSNR.

Writes ``speed_error.json`` (every point, the Pareto-optimal ones marked) and ``speed_error.png`` (time vs
LPIPS* and time vs PSNR with the Pareto fronts) into ``--out``. Example (small, CPU)::

    python benchmarks/speed_error.py go_pipeline/examples/basket --profile example \\
        --grid coarse.iterations=100,300,1000 --grid scene.max_size=80,160 --out /tmp/speed_error
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
import time
from pathlib import Path
from typing import Any

import yaml


def parse_grid(items: list[str]) -> dict[str, list[Any]]:
    grid: dict[str, list[Any]] = {}
    for item in items:
        key, _, values = item.partition("=")
        if "." not in key or not values:
            raise SystemExit(f"--grid wants step.param=v1,v2,... got {item!r}")
        grid[key.strip()] = [yaml.safe_load(v) for v in values.split(",")]
    return grid


def parse_ablations(items: list[str]) -> dict[str, dict[str, Any]]:
    """``name:step.param=value;step.param=value`` → {name: overrides}; always includes ``full`` (none)."""
    out: dict[str, dict[str, Any]] = {"full": {}}
    for item in items:
        name, _, rest = item.partition(":")
        sets = {}
        for pair in filter(None, rest.split(";")):
            k, _, v = pair.partition("=")
            sets[k.strip()] = yaml.safe_load(v)
        out[name.strip()] = sets
    return out


def configurations(grid: dict[str, list[Any]], ablations: dict[str, dict[str, Any]]) -> list[dict[str, Any]]:
    keys = list(grid)
    configs = []
    for values in itertools.product(*(grid[k] for k in keys)):
        for ab_name, ab in ablations.items():
            overrides = dict(zip(keys, values, strict=True))
            overrides.update(ab)
            label = ", ".join(f"{k.split('.')[-1]}={v}" for k, v in zip(keys, values, strict=True))
            configs.append(
                {
                    "label": label + ("" if ab_name == "full" else f", {ab_name}"),
                    "ablation": ab_name,
                    "overrides": overrides,
                }
            )
    return configs


def pareto(points: list[dict], x: str, y: str, maximize_y: bool = False) -> list[int]:
    """Indices of the points not dominated in (x lower, y lower / higher); points with None are skipped."""
    idx = [i for i, p in enumerate(points) if p.get(x) is not None and p.get(y) is not None]
    sign = -1.0 if maximize_y else 1.0
    front = []
    for i in idx:
        xi, yi = points[i][x], sign * points[i][y]
        dominated = any(
            points[j][x] <= xi
            and sign * points[j][y] <= yi
            and (points[j][x] < xi or sign * points[j][y] < yi)
            for j in idx
            if j != i
        )
        if not dominated:
            front.append(i)
    return sorted(front, key=lambda i: points[i][x])


def run_sweep(
    scene: Path,
    configs: list[dict],
    workdir: Path,
    profile: str | None,
    pipeline: str | None,
    until: str,
    seed: int,
    in_process: bool,
) -> list[dict]:
    from go_pipeline.reporting.run_report import build_report
    from go_pipeline.runner import run_pipeline

    points = []
    for n, cfg in enumerate(configs, 1):
        t0 = time.perf_counter()
        point: dict[str, Any] = {**cfg}
        try:
            run_pipeline(
                scene,
                workdir=workdir,
                profile=profile,
                overrides=cfg["overrides"],
                until=until,
                seed=seed,
                pipeline_path=pipeline,
                in_process=in_process,
                quiet=True,
            )
            rep = build_report(scene, workdir, pipeline)
            mean = (rep["metrics"] or {}).get("mean", {})
            point.update(
                status="ok",
                time_s=rep["totals"]["wall_s"],
                cpu_s=rep["totals"]["cpu_s"],
                psnr=mean.get("psnr"),
                ssim=mean.get("ssim"),
                lpips_vgg=mean.get("lpips_vgg"),
                lpips_alex=mean.get("lpips_alex"),
                num_gaussians=rep["result"]["num_gaussians"],
                model=rep["result"]["model"],
                step_wall_s={s["name"]: s["wall_s"] for s in rep["steps"]},
            )
            lp = point["lpips_vgg"] if point["lpips_vgg"] is not None else point["lpips_alex"]
            point["lpips"] = lp
            point["lpips_net"] = (
                "vgg" if point["lpips_vgg"] is not None else ("alex" if lp is not None else None)
            )
        except Exception as exc:  # noqa: BLE001 - a failing setting is a result too
            point.update(status="failed", error=str(exc).splitlines()[0] if str(exc) else type(exc).__name__)
        point["sweep_wall_s"] = time.perf_counter() - t0
        print(
            f"[{n}/{len(configs)}] {cfg['label']}: "
            + (
                f"{point['time_s']:.1f} s, PSNR {_f(point['psnr'])}, LPIPS {_f(point['lpips'], '.4f')}"
                if point["status"] == "ok"
                else f"FAILED {point['error']}"
            ),
            flush=True,
        )
        points.append(point)
    return points


def _f(v, spec=".2f"):
    return "n/a" if v is None else format(v, spec)


def plot(points: list[dict], fronts: dict[str, list[int]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), dpi=110)
    for ax, (metric, label, front_key) in zip(
        axes,
        [("lpips", "LPIPS (lower is better)", "lpips"), ("psnr", "PSNR dB (higher is better)", "psnr")],
        strict=True,
    ):
        ok = [p for p in points if p.get("status") == "ok" and p.get(metric) is not None]
        abl = sorted({p["ablation"] for p in ok})
        for k, name in enumerate(abl):
            sel = [p for p in ok if p["ablation"] == name]
            ax.scatter(
                [p["time_s"] for p in sel],
                [p[metric] for p in sel],
                label=name,
                zorder=3,
                marker="osD^v<>"[k % 7],
            )
        for p in ok:
            ax.annotate(
                p["label"], (p["time_s"], p[metric]), fontsize=6, xytext=(3, 3), textcoords="offset points"
            )
        front = [points[i] for i in fronts[front_key]]
        if front:
            ax.step(
                [p["time_s"] for p in front],
                [p[metric] for p in front],
                where="post",
                color="k",
                lw=1,
                alpha=0.6,
                label="Pareto front",
            )
        ax.set_xlabel("pipeline wall time (s)")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        if ok:
            ax.legend(fontsize=7)
    net = next((p["lpips_net"] for p in points if p.get("lpips_net")), None)
    fig.suptitle(f"speed vs error (LPIPS-{net or 'n/a'})")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene", type=Path)
    ap.add_argument(
        "--grid",
        action="append",
        default=[],
        metavar="STEP.PARAM=V1,V2",
        help="a swept param (repeatable; default coarse.iterations=300,1000,3000 × scene.max_size=100,200)",
    )
    ap.add_argument(
        "--ablation",
        action="append",
        default=[],
        metavar="NAME:STEP.PARAM=V;...",
        help="an extra override set compared with the full pipeline (repeatable)",
    )
    ap.add_argument(
        "--set",
        dest="sets",
        action="append",
        default=[],
        metavar="STEP.PARAM=VALUE",
        help="a fixed override for every configuration (repeatable)",
    )
    ap.add_argument("--profile", default=None)
    ap.add_argument("--pipeline", default=None)
    ap.add_argument("--until", default="eval")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workdir", type=Path, default=None, help="shared work dir (default OUT/work)")
    ap.add_argument("--out", type=Path, default=Path("speed_error_out"))
    ap.add_argument(
        "--in-process", action="store_true", help="run steps in this process (faster, less exact)"
    )
    args = ap.parse_args(argv)

    defaults = not args.grid and not args.ablation
    grid = parse_grid(args.grid or ["coarse.iterations=300,1000,3000", "scene.max_size=100,200"])
    ablations = parse_ablations(["no_floaters:coarse.floaters=false"] if defaults else args.ablation)
    configs = configurations(grid, ablations)
    fixed = {k: v[0] for k, v in parse_grid(args.sets).items()} if args.sets else {}
    for cfg in configs:
        cfg["overrides"] = {**fixed, **cfg["overrides"]}
    args.out.mkdir(parents=True, exist_ok=True)
    workdir = args.workdir or (args.out / "work")
    print(f"{len(configs)} configurations on {args.scene}", flush=True)
    points = run_sweep(
        args.scene, configs, workdir, args.profile, args.pipeline, args.until, args.seed, args.in_process
    )
    fronts = {"lpips": pareto(points, "time_s", "lpips"), "psnr": pareto(points, "time_s", "psnr", True)}
    for key, idx in fronts.items():
        for i in idx:
            points[i][f"pareto_{key}"] = True
    result = {
        "schema": "go-pipeline/speed-error",
        "version": 1,
        "scene": str(args.scene),
        "grid": grid,
        "fixed": fixed,
        "profile": args.profile,
        "points": points,
        "pareto": fronts,
    }
    (args.out / "speed_error.json").write_text(
        json.dumps(result, indent=2, sort_keys=True, default=str) + "\n"
    )
    plot(points, fronts, args.out / "speed_error.png")
    print(f"wrote {args.out / 'speed_error.json'} and {args.out / 'speed_error.png'}")
    for key, idx in fronts.items():
        print(f"Pareto ({key}): " + "; ".join(points[i]["label"] for i in idx))
    return 0 if all(p["status"] == "ok" for p in points) else 1


if __name__ == "__main__":
    sys.exit(main())
