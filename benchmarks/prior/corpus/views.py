"""The cameras and lighting of one corpus object, drawn from its own seed (``derive_seed(seed, name)``).

Training views: 4 around the object, azimuth offset uniform in [0, 360), each view ±``AZ_JITTER`` off the
even spacing; one elevation per object uniform in ``TRAIN_ELEVATION``, each view ±``EL_JITTER`` off it (real
captures are not on a perfect ring). Novel views: ``n_novel`` with stratified elevations over
``NOVEL_ELEVATION`` and evenly spread azimuths (jittered), so the set covers what the four views miss
(above, below, between). Lighting: one of Blender's bundled studio-light HDRIs, turned and scaled at random,
plus a soft sun of random strength and direction (off in a quarter of the objects).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from go_core.seeding import numpy_rng

TRAIN_ELEVATION = (0.0, 35.0)
NOVEL_ELEVATION = (-10.0, 60.0)
AZ_JITTER = 6.0
EL_JITTER = 3.0
HDRIS = ("studio", "courtyard", "forest", "city", "interior", "sunrise", "sunset", "night")


@dataclass(frozen=True)
class ObjectViews:
    train: list[tuple[float, float]]  # (azimuth, elevation) in degrees
    novel: list[tuple[float, float]]
    hdri: str
    hdri_strength: float
    hdri_rotation_deg: float
    sun_strength: float
    sun_elevation_deg: float
    sun_azimuth_deg: float

    def to_dict(self) -> dict:
        return asdict(self)


def draw_views(seed: int, name: str, n_novel: int, n_train: int = 4) -> ObjectViews:
    """The views and lighting of object ``name`` (the same for the same seed, name and counts)."""
    if n_train < 1 or n_novel < 1:
        raise ValueError(f"need at least one training and one novel view, got {n_train} and {n_novel}")
    rng = numpy_rng(int(seed), "corpus_views", name)
    az0 = rng.uniform(0.0, 360.0)
    el0 = rng.uniform(*TRAIN_ELEVATION)
    train = []
    for i in range(n_train):
        az = (az0 + i * 360.0 / n_train + rng.uniform(-AZ_JITTER, AZ_JITTER)) % 360.0
        el = float(np.clip(el0 + rng.uniform(-EL_JITTER, EL_JITTER), *TRAIN_ELEVATION))
        train.append((round(float(az), 4), round(el, 4)))
    lo, hi = NOVEL_ELEVATION
    edges = np.linspace(lo, hi, n_novel + 1)
    els = rng.uniform(edges[:-1], edges[1:])
    rng.shuffle(els)
    step = 360.0 / n_novel
    novel = [
        (
            round(float((az0 + (i + 0.5) * step + rng.uniform(-0.3, 0.3) * step) % 360.0), 4),
            round(float(e), 4),
        )
        for i, e in enumerate(els)
    ]
    sun = float(rng.uniform(1.0, 3.0)) if rng.random() >= 0.25 else 0.0
    return ObjectViews(
        train=train,
        novel=novel,
        hdri=str(rng.choice(HDRIS)),
        hdri_strength=round(float(rng.uniform(0.7, 1.4)), 4),
        hdri_rotation_deg=round(float(rng.uniform(0.0, 360.0)), 4),
        sun_strength=round(sun, 4),
        sun_elevation_deg=round(float(rng.uniform(20.0, 70.0)), 4),
        sun_azimuth_deg=round(float(rng.uniform(0.0, 360.0)), 4),
    )


def camera_to_world(az_deg: float, el_deg: float, radius: float) -> np.ndarray:
    """OpenGL camera-to-world matrix of a camera at (azimuth, elevation, radius) looking at the origin."""
    az, el = math.radians(az_deg), math.radians(el_deg)
    eye = radius * np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    f = -eye / np.linalg.norm(eye)
    x = np.cross(f, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = x, np.cross(x, f), -f, eye
    return m
