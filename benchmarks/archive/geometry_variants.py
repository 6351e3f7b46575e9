"""Table of geometry_dev.py runs side by side: per variant (a training change or a mesh setting) and scene,
the coarse mesh's Chamfer-L1 / F@1% / normal consistency / silhouette IoU, the coarse model's test PSNR /
LPIPS* and its training seconds, with each figure's change against the defaults (issue #35, item 4: a change
is on by default only if it measures better on geometry and no worse than −0.1 dB on test PSNR).

    python benchmarks/archive/geometry_variants.py --defaults benchmarks/results/geometry_dev.json \\
        --variant dn=/tmp/geo/dn.json inside=/tmp/geo/inside.json \\
        --out benchmarks/results/geometry_dev_variants.json

``--images NAME=FILE`` adds test-view image metrics (``{scene: {psnr, ...}}``) to a run that lacks them
(geometry_dev.py measures them since this table was introduced; older runs did not).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

GEOMETRY = ("chamfer_l1", "fscore_1pct", "fscore_2pct", "normal_consistency", "silhouette_iou")
IMAGES = ("psnr", "lpips_star", "see_through_pct")


def rows(run: dict, images: dict | None) -> dict:
    """Per scene: the coarse mesh's geometry, the model's images and seconds, the hull's Chamfer / F@1%."""
    out = {}
    for scene, s in run["scenes"].items():
        row = {k: s["coarse"][k] for k in GEOMETRY}
        row.update({f"hull_{k}": s["hull"][k] for k in ("chamfer_l1", "fscore_1pct")})
        row.update(
            {
                k: v
                for k, v in (s.get("coarse_images") or (images or {}).get(scene, {})).items()
                if k in IMAGES
            }
        )
        row["coarse_cpu_s"] = s.get("coarse_model", {}).get("coarse_cpu_s")
        row["mesh_step_s"] = s["seconds"]["mesh_step_total"]
        out[scene] = row
    return out


def load(spec: str) -> tuple[str, dict]:
    """``NAME=FILE[,FILE...]`` → (name, merged scenes of the runs, with their protocol)."""
    name, files = spec.split("=", 1)
    merged: dict = {"scenes": {}}
    for f in files.split(","):
        run = json.loads(Path(f).read_text())
        merged["scenes"].update(run["scenes"])
        for k in ("samples_per_surface", "seed", "mesh_params", "coarse_overrides", "mesh_overrides"):
            if k in run:
                merged.setdefault("protocol", {})[k] = run[k]
    return name, merged


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--defaults", required=True, help="FILE[,FILE...]: the runs at the defaults")
    ap.add_argument("--variant", nargs="*", default=[], metavar="NAME=FILE[,FILE...]")
    ap.add_argument("--images", nargs="*", default=[], metavar="NAME=FILE")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    images = {}
    for spec in args.images:
        name, f = spec.split("=", 1)
        images[name] = json.loads(Path(f).read_text())
    runs = dict(load(s) for s in [f"defaults={args.defaults}", *args.variant])
    table = {name: rows(run, images.get(name)) for name, run in runs.items()}
    base = table["defaults"]
    changes = {
        name: {
            scene: {k: v - base[scene][k] for k, v in row.items() if k in base.get(scene, {})
                    and isinstance(v, float) and isinstance(base[scene][k], float)}
            for scene, row in t.items() if scene in base
        }
        for name, t in table.items() if name != "defaults"
    }  # fmt: skip
    out = {
        "benchmark": "geometry_variants",
        "protocols": {name: run.get("protocol", {}) for name, run in runs.items()},
        "table": table,
        "change_vs_defaults": changes,
    }
    args.out.write_text(json.dumps(out, indent=2, sort_keys=True))
    for name, t in table.items():
        for scene, r in sorted(t.items()):
            ps = f"{r['psnr']:.2f}" if "psnr" in r else "-"
            ratio = r["chamfer_l1"] / r["hull_chamfer_l1"]
            print(f"{name:10s} {scene:14s} chamfer {r['chamfer_l1']:.4f} ({ratio:.2f}x hull)"
                  f"  F@1% {r['fscore_1pct']:.3f} (hull {r['hull_fscore_1pct']:.3f})  PSNR {ps}")  # fmt: skip


if __name__ == "__main__":
    main()
