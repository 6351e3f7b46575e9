"""More corpus objects for issue 34 from the ``pybullet==3.2.7`` wheel's ``pybullet_data``: white, smooth,
concave and flat-coloured shapes, which the LIBERO-PRO objects lack (white_bowl and plate are where every
repair prior loses to ``realesr``).

Fetches the wheel once with ``pip download --no-deps`` into ``--cache`` (SHA-256 pinned) and writes an asset
tree that ``benchmarks/prior/repair_corpus.py --assets TREE --extend-index`` reads: the LIBERO-PRO families
linked from the corpus cache, plus the family ``pybullet_objects`` with one folder per object (its OBJ, an MTL
and its texture). Objects without a material get one: the named objects a white one (``WHITE``), the random
blobs (``random_urdfs/NNN``) the flat colour their URDF gives them.

    python benchmarks/prior/corpus_pybullet.py --tree ~/go-corpus-assets
    python benchmarks/prior/repair_corpus.py --assets ~/go-corpus-assets --out ~/go-corpus --extend-index \\
        --budget-min 30 --manifest benchmarks/results/repair_corpus.json
"""

from __future__ import annotations

import argparse
import hashlib
import re
import subprocess
import sys
import zipfile
from pathlib import Path

WHEEL = "pybullet-3.2.7-cp311-cp311-manylinux_2_17_x86_64.manylinux2014_x86_64.whl"
WHEEL_SHA256 = "5d858abf7c12a21ef3ed351cf81dac1b5e486ec25c9ab59bfc84beb89034edff"
FAMILY = "pybullet_objects"
WHITE = (0.9, 0.9, 0.9)
# object folder -> (OBJ inside pybullet_data, texture files it needs, beside the OBJ as the MTL names them)
NAMED = {
    "mug": ("objects/mug.obj", ()),
    "bunny": ("bunny.obj", ()),
    "tray": ("tray/tray_textured.obj", ("tray/tray.jpg",)),
    "duck": ("duck.obj", ("duckCM.png",)),
    "torus": ("torus/torus_textured.obj", ("cube.png",)),
    "concave_box": ("toys/concave_box.obj", ("checker_grid.jpg",)),
    "cylinder": ("toys/cylinder.obj", ()),
    "soccerball": ("soccerball.obj", ("colors16.png",)),
    "jenga": ("jenga/jenga.obj", ("jenga/jenga.png",)),
    "domino": ("domino/domino.obj", ("domino/domino.jpg",)),
}
BLOBS = 12  # random_urdfs/000 .. 011


def fetch_wheel(cache: Path) -> Path:
    path = cache / WHEEL
    if not path.exists():
        cache.mkdir(parents=True, exist_ok=True)
        cmd = [sys.executable, "-m", "pip", "download", "--no-deps", "pybullet==3.2.7", "-d", str(cache)]
        subprocess.run(cmd, check=True)
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    if digest != WHEEL_SHA256:
        sys.exit(f"error: {path}: SHA-256 {digest}, expected {WHEEL_SHA256}")
    return path


def _with_material(obj_text: str, name: str, colour: tuple[float, float, float]) -> tuple[str, str]:
    """The OBJ text without its own material lines, using ``name``.mtl, and that MTL (flat ``colour``)."""
    body = [line for line in obj_text.splitlines() if not line.startswith(("mtllib", "usemtl"))]
    mtl = f"newmtl {name}\nKd {colour[0]:.3f} {colour[1]:.3f} {colour[2]:.3f}\nNs 50\nillum 2\n"
    return f"mtllib {name}.mtl\nusemtl {name}\n" + "\n".join(body) + "\n", mtl


def write_named(z: zipfile.ZipFile, family_dir: Path) -> None:
    for name, (obj, textures) in NAMED.items():
        out = family_dir / name
        out.mkdir(parents=True, exist_ok=True)
        text = z.read(f"pybullet_data/{obj}").decode()
        mtllib = re.search(r"^mtllib\s+(\S+)", text, re.M)
        if mtllib is None:
            text, mtl = _with_material(text, name, WHITE)
            (out / f"{name}.mtl").write_text(mtl)
        else:
            mtl = z.read(f"pybullet_data/{Path(obj).parent / mtllib.group(1)}".replace("/./", "/")).decode()
            mtl = re.sub(r"map_Kd\s+(\S+)", lambda m: f"map_Kd {Path(m.group(1)).name}", mtl)
            (out / mtllib.group(1)).write_text(mtl)
        (out / f"{name}.obj").write_text(text)
        for tex in textures:
            (out / Path(tex).name).write_bytes(z.read(f"pybullet_data/{tex}"))


def write_flat_object(z: zipfile.ZipFile, family_dir: Path, name: str, obj: str, colour) -> None:
    """``family_dir/name/``: the OBJ ``pybullet_data/obj`` with one flat-``colour`` material of its own."""
    text, mtl = _with_material(z.read(f"pybullet_data/{obj}").decode(), name, tuple(colour))
    out = family_dir / name
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{name}.obj").write_text(text)
    (out / f"{name}.mtl").write_text(mtl)


def write_blobs(z: zipfile.ZipFile, family_dir: Path) -> None:
    for i in range(BLOBS):
        stem = f"random_urdfs/{i:03d}/{i:03d}"
        urdf = z.read(f"pybullet_data/{stem}.urdf").decode()
        rgba = [float(x) for x in re.search(r'rgba="([^"]+)"', urdf).group(1).split()]
        write_flat_object(z, family_dir, f"blob_{i:03d}", f"{stem}.obj", rgba[:3])


def link_libero(tree: Path, cache: Path) -> Path:
    """``tree``'s assets folder with every LIBERO-PRO family of the unpacked wheels (fetched once into
    ``cache``) linked into it; returns that folder."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from corpus.assets import ASSETS_SUBDIR
    from repair_corpus import fetch_assets

    libero = fetch_assets(cache) / ASSETS_SUBDIR
    assets = tree / ASSETS_SUBDIR
    assets.mkdir(parents=True, exist_ok=True)
    for family in sorted(p for p in libero.iterdir() if p.is_dir()):
        link = assets / family.name
        if not link.exists():
            link.symlink_to(family.resolve(), target_is_directory=True)
    return assets


def main(argv: list[str]) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tree", type=Path, required=True, help="asset tree to write")
    ap.add_argument("--cache", type=Path, default=Path.home() / ".cache" / "go-pipeline-corpus")
    args = ap.parse_args(argv)
    assets = link_libero(args.tree, args.cache)
    with zipfile.ZipFile(fetch_wheel(args.cache / "wheels")) as z:
        write_named(z, assets / FAMILY)
        write_blobs(z, assets / FAMILY)
    print(f"{assets}: {len(NAMED)} named objects and {BLOBS} blobs in {FAMILY}")


if __name__ == "__main__":
    main(sys.argv[1:])
