"""``initial_poses.json``: training poses from another source (a phone's AR session, another SfM, a
perturbation study), to start from instead of the folder's own (``scene.poses: initial``).

The folder's own poses stay the reference frame of the test views, exactly as for estimated poses: the
model lives in the frame of the initial (then refined) cameras and evaluation aligns the test poses to it
(docs/evaluation.md, CF protocol). Format: NeRF-synthetic style, camera-to-world in OpenGL axes::

    {"frames": [{"file_path": "./train/r_0", "transform_matrix": [[...4 rows...]]}, ...]}

A frame is matched to a training view by its ``file_path`` (the view name: ``./train/r_0`` is
``train_r_0``); every view needs one. Intrinsics stay the folder's.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path, PurePosixPath

import numpy as np

from go_core.camera import Camera
from go_core.errors import SceneError
from go_core.io.images import IMAGE_EXTENSIONS

INITIAL_POSES_FILE = "initial_poses.json"


def _frame_name(file_path: str) -> str:
    """The view name of a frame's ``file_path`` (as ``go_core.scene.common.view_name``: ./train/r_0 →
    train_r_0)."""
    p = PurePosixPath(file_path)
    if p.suffix.lower() in {e.lower() for e in IMAGE_EXTENSIONS}:
        p = p.with_suffix("")
    return p.as_posix().replace("/", "_")


def read_initial_poses(folder: str | Path, cameras: list[Camera]) -> list[Camera]:
    """``cameras`` with their poses replaced by those of ``folder/initial_poses.json`` (module docstring);
    a SceneError naming the file and the problem otherwise."""
    path = Path(folder) / INITIAL_POSES_FILE
    if not path.is_file():
        raise SceneError(f"scene.poses=initial needs {INITIAL_POSES_FILE} in the scene folder", path)
    try:
        frames = json.loads(path.read_text())["frames"]
        by_name = {_frame_name(f["file_path"]): f["transform_matrix"] for f in frames}
    except (ValueError, KeyError, TypeError) as exc:
        raise SceneError(
            f"not a transforms file with frames (file_path, transform_matrix): {exc}", path
        ) from None
    out = []
    for cam in cameras:
        if cam.name not in by_name:
            raise SceneError(f"no initial pose for the training view {cam.name!r}", path)
        c2w = np.asarray(by_name[cam.name], np.float64)
        if c2w.shape != (4, 4) or not np.isfinite(c2w).all():
            raise SceneError(f"the pose of {cam.name!r} is not a finite 4x4 matrix", path)
        R = c2w[:3, :3]
        if np.abs(R.T @ R - np.eye(3)).max() > 1e-4 or np.linalg.det(R) < 0:
            raise SceneError(f"the rotation of {cam.name!r} is not a rotation (orthonormal, det +1)", path)
        posed = Camera.from_opengl_c2w(cam.name, cam.width, cam.height, cam.K, c2w)
        out.append(replace(cam, world_to_cam=posed.world_to_cam))
    return out
