"""The corpus's train / validation split, by geometry: recoloured copies of one mesh (``butter`` and
``green_butter``) form one group and land in the same split, so no validation shape is seen in training."""

from __future__ import annotations

import math

from go_core.seeding import derive_seed

from .exclusion import Shape, same_mesh


def geometry_groups(shapes: list[Shape]) -> dict[str, str]:
    """name -> group (the first name, in the given order, of its group): copies of one mesh (recoloured or
    rescaled: ``corpus.exclusion.same_mesh``) are one group."""
    group: dict[str, str] = {}
    for i, s in enumerate(shapes):
        group.setdefault(s.name, s.name)
        for t in shapes[i + 1 :]:
            if t.name not in group and same_mesh(t, s):
                group[t.name] = group[s.name]
    return group


def split_groups(groups: list[str], seed: int, val_fraction: float) -> set[str]:
    """The validation groups: ``ceil(val_fraction · n)`` of them (at least one when there are two or more),
    chosen by a seeded order of their names."""
    if not 0.0 <= val_fraction < 1.0:
        raise ValueError(f"val_fraction must be in [0, 1), got {val_fraction}")
    n = len(groups)
    k = math.ceil(val_fraction * n) if n > 1 else 0
    ranked = sorted(groups, key=lambda g: derive_seed(int(seed), "corpus_split", g))
    return set(ranked[:k])
