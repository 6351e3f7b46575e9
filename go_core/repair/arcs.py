"""Distance-aware novel views for Gaussian repair.

An ellipse is fitted to the TRAINING (reference) cameras around their look-at centre. The ellipse points
nearest to the N reference views split it into N arcs; novel views are drawn from the middle ``keep``
fraction (paper: 80%) of each arc, so no repair view lies in the 10% of an arc next to a reference view.
Test cameras never enter: only the training cameras shape the ellipse and the arcs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from go_core.camera import Camera, Ellipse, fit_ellipse, look_at, raise_towards

TWO_PI = 2.0 * np.pi


@dataclass(frozen=True)
class RepairView:
    camera: Camera
    arc: int  # index of the arc (path) it was drawn from
    theta: float  # ellipse parameter in [0, 2π)


@dataclass(frozen=True)
class RepairArcs:
    """The N arcs between consecutive reference views (in ellipse-parameter order)."""

    ellipse: Ellipse
    references: list[Camera]  # sorted by ellipse angle
    ref_thetas: np.ndarray  # [N] ellipse angles of the references, increasing, in [0, 2π)
    keep: float  # fraction of each arc that is sampled (0.8 in the paper), centred

    @staticmethod
    def from_cameras(train_cameras: list[Camera], keep: float) -> RepairArcs:
        if len(train_cameras) < 2:
            raise ValueError("repair arcs need at least 2 training cameras")
        if not 0.0 < keep <= 1.0:
            raise ValueError(f"keep fraction must be in (0, 1], got {keep}")
        ellipse = fit_ellipse(train_cameras)
        thetas = np.array([float(ellipse.angle_of(c.center)[0]) for c in train_cameras])
        order = np.argsort(thetas)
        return RepairArcs(ellipse, [train_cameras[i] for i in order], thetas[order], float(keep))

    def __len__(self) -> int:
        return len(self.references)

    def arc_bounds(self, i: int) -> tuple[float, float]:
        """Start angle and (positive) angular length of arc i, from reference i to reference i+1."""
        start = self.ref_thetas[i]
        end = self.ref_thetas[(i + 1) % len(self)]
        length = (end - start) % TWO_PI
        if length == 0.0:
            length = TWO_PI
        return float(start), float(length)

    def sample_range(self, i: int) -> tuple[float, float]:
        """(first, last) angle of the sampled middle part of arc i (unwrapped: last may exceed 2π)."""
        start, length = self.arc_bounds(i)
        margin = 0.5 * (1.0 - self.keep) * length
        return start + margin, start + length - margin

    def arc_position(self, theta: float) -> tuple[int, float]:
        """(arc index, fraction along that arc in [0, 1)) of an ellipse angle."""
        for i in range(len(self)):
            start, length = self.arc_bounds(i)
            f = ((theta - start) % TWO_PI) / length
            if f < 1.0:
                return i, float(f)
        raise AssertionError("angle on no arc")  # arcs cover the whole ellipse

    def sample(
        self, rng: np.random.Generator, per_arc: int, like: Camera | None = None, name_prefix: str = "repair"
    ) -> list[RepairView]:
        """``per_arc`` views drawn uniformly from the middle part of every arc; each looks at the target with
        the intrinsics of the nearer reference of its arc (or ``like``)."""
        views = []
        for i in range(len(self)):
            lo, hi = self.sample_range(i)
            for j in range(per_arc):
                theta = float(np.mod(rng.uniform(lo, hi), TWO_PI))
                start, length = self.arc_bounds(i)
                near = (
                    self.references[i]
                    if ((theta - start) % TWO_PI) < 0.5 * length
                    else self.references[(i + 1) % len(self)]
                )
                cam = self.ellipse.camera(f"{name_prefix}_{i}_{j}", theta, like or near)
                views.append(RepairView(cam, i, theta))
        return views

    def reference_positions(self) -> np.ndarray:
        return np.stack([c.center for c in self.references])


def with_raised_twins(views: list[RepairView], ellipse: Ellipse, degrees: float) -> list[RepairView]:
    """Each view followed by its twin ``<name>_up``: raised by ``degrees`` of elevation towards the
    ellipse's normal (the cameras' up) about its target, at the same distance, looking at the target with
    the same intrinsics (``repair.lift_deg``: real captures' test views from above)."""
    out = []
    for v in views:
        c = v.camera
        position = raise_towards(ellipse.point(v.theta), ellipse.target, ellipse.normal, degrees)
        twin = look_at(f"{c.name}_up", position, ellipse.target, ellipse.normal, c.K, c.width, c.height)
        out += [v, RepairView(twin, v.arc, v.theta)]
    return out
