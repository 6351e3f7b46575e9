"""Tracks and triangulation: verified matches chained into tracks (union-find over (image, keypoint); a
track that hits one image twice is dropped), linear DLT triangulation, and the leave-one-out reprojection
errors the pose check (go_core.poses.check) judges each view by: a track's point is triangulated from its
OTHER views and reprojected into the held-out one, so a wrong pose cannot pull the point towards itself."""

from __future__ import annotations

import numpy as np

from go_core.camera import Camera


def build_tracks(num_keypoints: list[int], matches: dict[tuple[int, int], np.ndarray]) -> list[np.ndarray]:
    """Union-find tracks: each an array [[view, keypoint], ...] with every view at most once, >= 2 views."""
    offsets = np.concatenate([[0], np.cumsum(num_keypoints)])
    parent = np.arange(int(offsets[-1]))

    def find(x: int) -> int:
        root = x
        while parent[root] != root:
            root = parent[root]
        while parent[x] != root:
            parent[x], x = root, parent[x]
        return root

    for (i, j), m in matches.items():
        for a, b in m:
            ra, rb = find(offsets[i] + a), find(offsets[j] + b)
            if ra != rb:
                parent[rb] = ra
    groups: dict[int, list[int]] = {}
    used = set()
    for (i, j), m in matches.items():
        used.update((offsets[i] + m[:, 0]).tolist())
        used.update((offsets[j] + m[:, 1]).tolist())
    for node in used:
        groups.setdefault(find(node), []).append(node)
    tracks = []
    for nodes in groups.values():
        view_of = np.searchsorted(offsets, nodes, side="right") - 1
        if len(set(view_of.tolist())) != len(nodes) or len(nodes) < 2:
            continue  # inconsistent track (one image twice) or trivial
        kp = np.asarray(nodes) - offsets[view_of]
        tracks.append(np.stack([view_of, kp], axis=1))
    return tracks


def triangulate_dlt(projections: np.ndarray, points2d: np.ndarray) -> np.ndarray:
    """Linear (DLT) triangulation of one point from P [K,3,4] and pixel coords [K,2]."""
    rows = []
    for P, (u, v) in zip(projections, points2d, strict=True):
        rows.append(u * P[2] - P[0])
        rows.append(v * P[2] - P[1])
    A = np.asarray(rows)
    A /= np.linalg.norm(A, axis=1, keepdims=True) + 1e-12
    _, _, vt = np.linalg.svd(A)
    X = vt[-1]
    return X[:3] / X[3] if abs(X[3]) > 1e-12 else np.full(3, np.nan)


def leave_one_out_errors(
    cameras: list[Camera], keypoints: list[np.ndarray], tracks: list[np.ndarray], min_views: int = 3
) -> list[list[float]]:
    """Per view, the reprojection errors (px) of its observations against points triangulated from the
    other views of each track (tracks with >= ``min_views`` views)."""
    P = np.stack([c.K @ c.world_to_cam[:3] for c in cameras])
    errors: list[list[float]] = [[] for _ in cameras]
    for track in tracks:
        if len(track) < min_views:
            continue
        vids, kps = track[:, 0], track[:, 1]
        xy = np.stack([keypoints[v][k] for v, k in zip(vids, kps, strict=True)])
        for t in range(len(track)):
            others = np.arange(len(track)) != t
            X = triangulate_dlt(P[vids[others]], xy[others])
            if not np.all(np.isfinite(X)):
                continue
            cam = cameras[vids[t]]
            uv, z = cam.project(X[None])
            zo = np.array([cameras[v].project(X[None])[1][0] for v in vids[others]])
            if z[0] <= 0 or np.any(zo <= 0):
                errors[vids[t]].append(float("inf"))  # behind a camera: certainly inconsistent
                continue
            errors[vids[t]].append(float(np.linalg.norm(uv[0] - xy[t])))
    return errors
