"""Write ``scene/mesh_world.npz`` (the ground-truth mesh in the cameras' frame) into every corpus object whose
folder was rendered before ``corpus_blender.py`` wrote it, so its geometry can be measured like a dev scene's.

Reads each object's ``render_job.json`` (the meshes, up axis and scene folder the render used) and runs the
same import and normalisation in Blender, rendering nothing::

    python benchmarks/corpus_meshes.py --corpus CORPUS [--bpy-python ~/.venvs/bpy/bin/python]
"""

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

BLENDER_SCRIPT = Path(__file__).resolve().parent / "corpus_blender.py"


def write_mesh(folder: Path, bpy_python: Path) -> bool:
    """``mesh_world.npz`` for one object folder; False when it already has one."""
    job = json.loads((folder / "render_job.json").read_text())
    target = Path(job["out"]) / "mesh_world.npz"
    if target.exists():
        return False
    with tempfile.NamedTemporaryFile("w", suffix=".json", delete=False) as fh:
        json.dump({**job, "mesh_only": True}, fh)
    proc = subprocess.run([str(bpy_python), str(BLENDER_SCRIPT), fh.name], capture_output=True, text=True)
    Path(fh.name).unlink()
    if proc.returncode != 0 or not target.exists():
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
        raise RuntimeError(f"{folder}: Blender failed ({proc.returncode}): {' | '.join(tail)}")
    return True


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--corpus", type=Path, required=True)
    ap.add_argument("--bpy-python", type=Path, default=Path.home() / ".venvs" / "bpy" / "bin" / "python")
    args = ap.parse_args(argv)
    folders = sorted(p.parent for p in (args.corpus / "objects").glob("*/render_job.json"))
    if not folders:
        print(f"{args.corpus}: no objects/*/render_job.json", file=sys.stderr)
        return 2
    made = sum(write_mesh(f, args.bpy_python) for f in folders)
    print(f"{made} meshes written, {len(folders) - made} already there")
    return 0


if __name__ == "__main__":
    sys.exit(main())
