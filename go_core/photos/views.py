"""A normalised world frame for SfM cameras, and the choice of N sparse training views spread around it.

Frame (as ``reference/transforms.json`` of the shared photo sets): the look-at centre of all cameras at the
origin, +Z the mean camera up, the median camera distance ``CAMERA_DISTANCE`` (NeRF-synthetic's ~4).

Choice (the paper's protocol for real captures: sparse views spread evenly around the object): azimuths
about +Z; for every registered photo as the anchor, the targets are ``anchor + k·360°/N`` and each target
takes the nearest photo not yet taken; the set scored best (largest azimuth miss, plus the elevation's
distance from the median elevation, both in degrees) wins; ties go to the earlier anchor. Deterministic.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from go_core.camera import Camera, look_at_point
from go_core.poses.similarity import Similarity

CAMERA_DISTANCE = 4.0
ELEVATION_WEIGHT = 0.5  # degrees of azimuth miss one degree off the median elevation costs


def normalising_similarity(cameras: list[Camera]) -> Similarity:
    """The similarity taking SfM's frame to the normalised one (module docstring)."""
    centre = look_at_point(cameras)
    up = np.mean([c.up for c in cameras], axis=0)
    up /= np.linalg.norm(up)
    x = np.cross([0.0, 1.0, 0.0] if abs(up[1]) < 0.9 else [1.0, 0.0, 0.0], up)
    x /= np.linalg.norm(x)
    rotation = np.stack([x, np.cross(up, x), up])  # rows: new axes in old coordinates
    dist = float(np.median([np.linalg.norm(c.center - centre) for c in cameras]))
    scale = CAMERA_DISTANCE / dist
    return Similarity(scale, rotation, -scale * rotation @ centre)


def azimuth_elevation(cameras: list[Camera]) -> tuple[np.ndarray, np.ndarray]:
    """Degrees, of each camera centre about the origin (azimuth about +Z, elevation above the XY plane)."""
    c = np.stack([cam.center for cam in cameras])
    az = np.degrees(np.arctan2(c[:, 1], c[:, 0])) % 360.0
    el = np.degrees(np.arctan2(c[:, 2], np.linalg.norm(c[:, :2], axis=1)))
    return az, el


def _angle(a: np.ndarray | float, b: np.ndarray | float) -> np.ndarray:
    return np.abs((np.asarray(a) - b + 180.0) % 360.0 - 180.0)


@dataclass
class ViewChoice:
    indices: list[int]  # sorted
    azimuth_deg: list[float]
    elevation_deg: list[float]
    gaps_deg: list[float]  # azimuth gaps between consecutive chosen views, going round
    score_deg: float  # largest azimuth miss + elevation term of the winning set

    def to_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


def choose_spread_views(cameras: list[Camera], n: int, exclude: frozenset[int] = frozenset()) -> ViewChoice:
    """``n`` cameras spread evenly in azimuth at a typical elevation (module docstring); cameras must be in
    the normalised frame. Cameras in ``exclude`` are never chosen."""
    az, el = azimuth_elevation(cameras)
    allowed = [i for i in range(len(cameras)) if i not in exclude]
    if n >= len(allowed):
        return _choice(allowed, az, el, 0.0)
    el_cost = ELEVATION_WEIGHT * np.abs(el - np.median(el))
    el_cost[list(exclude)] = np.inf
    best: tuple[float, list[int]] | None = None
    for anchor in allowed:
        taken: list[int] = []
        miss = 0.0
        for k in range(n):
            cost = _angle(az, az[anchor] + k * 360.0 / n) + el_cost
            cost[taken] = np.inf
            j = int(np.argmin(np.round(cost, 9)))
            taken.append(j)
            miss = max(miss, float(cost[j]))
        if best is None or round(miss, 9) < round(best[0], 9):
            best = (miss, taken)
    assert best is not None
    return _choice(sorted(best[1]), az, el, best[0])


def _choice(picked: list[int], az: np.ndarray, el: np.ndarray, score: float) -> ViewChoice:
    a = sorted(float(az[i]) for i in picked)
    gaps = [(a[(k + 1) % len(a)] - a[k]) % 360.0 or 360.0 for k in range(len(a))] if len(a) > 1 else []
    return ViewChoice(
        picked,
        [round(float(az[i]), 2) for i in picked],
        [round(float(el[i]), 2) for i in picked],
        [round(g, 2) for g in gaps],
        round(score, 3),
    )
