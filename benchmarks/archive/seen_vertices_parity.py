"""seen_vertices before and after its surface test became tsdf.PackedView.lookup (issue 35): both on the same
vertices and fusion views, through the real mesh step (in process, forced) on dev scenes' final models.

The old function is read from git (``--old-commit``) and run beside the new one on every call the mesh step
makes; the step keeps the new one's answer. Writes, per scene, the vertices and how many each calls seen.

    python benchmarks/archive/seen_vertices_parity.py --data ../shared/data/dev --workroot W \
        --scenes alphabet_soup --old-commit a4ae621 --out benchmarks/results/mesh_seen_vertices_parity.json
"""

from __future__ import annotations

import argparse
import json
import subprocess
from pathlib import Path

import go_core.mesh.extract as extract

# the models repair_dev.py's prior2_pretrained variant made (cached in the work dirs)
OVERRIDES = {"weights.compact_model": "go-repair-prior-2", "tune.finetune": False}


def old_seen_vertices(commit: str):
    """``seen_vertices`` as it was at ``commit`` (run in the module's namespace)."""
    source = subprocess.run(
        ["git", "show", f"{commit}:go_core/mesh/extract.py"], capture_output=True, text=True, check=True
    ).stdout
    start = source.index("def seen_vertices(")
    namespace = dict(extract.__dict__)
    exec(source[start : source.index("\ndef ", start + 1)], namespace)  # noqa: S102 (the repository's own code)
    return namespace["seen_vertices"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--workroot", type=Path, required=True)
    ap.add_argument("--scenes", nargs="+", required=True)
    ap.add_argument("--old-commit", required=True)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    from go_pipeline.runner import run_pipeline

    old, new, calls = old_seen_vertices(args.old_commit), extract.seen_vertices, []

    def both(vertices, views, rule):
        a, b = new(vertices, views, rule), old(vertices, views, rule)
        calls.append({"vertices": len(vertices), "seen_new": int(a.sum()), "seen_old": int(b.sum()),
                      "differ": int((a != b).sum())})  # fmt: skip
        return a

    extract.seen_vertices = both
    result = {"old_commit": args.old_commit, "overrides": OVERRIDES, "scenes": {}}
    for scene in args.scenes:
        calls.clear()
        workdir = args.workroot / scene
        run_pipeline(args.data / scene, workdir=workdir, until="mesh", in_process=True, quiet=True,
                     overrides=OVERRIDES, force=["mesh"])  # fmt: skip
        result["scenes"][scene] = list(calls)
        print(scene, calls, flush=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
