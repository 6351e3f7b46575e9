"""Builders of small scene folders (NeRF-synthetic json and COLMAP) for the scene tests (no tests here)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from go_core.camera import Camera, look_at
from go_core.io.images import write_png


def disk_rgba(w: int, h: int, seed: int, radius: float = 0.3) -> np.ndarray:
    """An RGBA float image: a random-coloured disk (alpha 1) on transparent black."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w]
    inside = ((xx + 0.5 - w / 2) ** 2 + (yy + 0.5 - h / 2) ** 2) < (radius * min(w, h)) ** 2
    rgba = np.zeros((h, w, 4), np.float32)
    rgba[..., :3] = rng.random(3, dtype=np.float32) * inside[..., None]
    rgba[..., 3] = inside
    return rgba


def ring_cameras(n: int, w: int = 32, h: int = 24, f: float = 30.0, elevation: float = 0.4) -> list[Camera]:
    """``n`` cameras on a ring at distance 3 looking at the origin, +Z up."""
    K = np.array([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1.0]])
    cams = []
    for i in range(n):
        az = 2 * np.pi * i / n + 0.3
        ce, se = np.cos(elevation), np.sin(elevation)
        pos = 3.0 * np.array([np.cos(az) * ce, np.sin(az) * ce, se])
        cams.append(look_at(f"v{i}", pos, np.zeros(3), np.array([0, 0, 1.0]), K, w, h))
    return cams


def write_nerf_scene(
    root: Path, n_train: int = 4, n_test: int = 2, w: int = 32, h: int = 24, rgba: bool = True
) -> Path:
    """A small NeRF-synthetic scene: train/r_i.png, test/r_i.png (RGBA, or RGB + masks/<split>/r_i.png)."""
    root.mkdir(parents=True, exist_ok=True)
    cams = ring_cameras(n_train + n_test, w, h)
    for split, sub in (("train", cams[:n_train]), ("test", cams[n_train:])):
        frames = []
        for i, cam in enumerate(sub):
            img = disk_rgba(w, h, seed=len(frames) + (0 if split == "train" else 100))
            if rgba:
                write_png(root / split / f"r_{i}.png", img)
            else:
                write_png(root / split / f"r_{i}.png", img[..., :3])
                write_png(root / "masks" / split / f"r_{i}.png", img[..., 3])
            frames.append({"file_path": f"./{split}/r_{i}", "transform_matrix": cam.opengl_c2w.tolist()})
        f = cams[0].K[0, 0]
        meta = {
            "camera_angle_x": float(2 * np.arctan(w / (2 * f))),
            "fl_x": f,
            "fl_y": f,
            "cx": w / 2,
            "cy": h / 2,
            "w": w,
            "h": h,
            "frames": frames,
        }
        (root / f"transforms_{split}.json").write_text(json.dumps(meta, indent=1))
    return root


def edit_json(path: Path, fn) -> None:
    data = json.loads(path.read_text())
    fn(data)
    path.write_text(json.dumps(data, indent=1))


def write_colmap_model(
    model_dir: Path,
    cameras: list[Camera],
    names: list[str],
    text: bool,
    model: str = "PINHOLE",
    extra_params: list[float] | None = None,
) -> None:
    """Write ``cameras``/``names`` as a COLMAP model (one COLMAP camera per view) with pycolmap."""
    import pycolmap

    recon = pycolmap.Reconstruction()
    for i, (cam, name) in enumerate(zip(cameras, names, strict=True)):
        K = cam.K
        if model == "SIMPLE_PINHOLE":
            params = [K[0, 0], K[0, 2], K[1, 2]]
        else:
            params = [K[0, 0], K[1, 1], K[0, 2], K[1, 2]] + list(extra_params or [])
        pc = pycolmap.Camera(model=model, width=cam.width, height=cam.height, params=params, camera_id=i + 1)
        recon.add_camera_with_trivial_rig(pc)
        im = pycolmap.Image(name=name, camera_id=i + 1, image_id=i + 1)
        recon.add_image_with_trivial_frame(im, pycolmap.Rigid3d(cam.world_to_cam[:3]))
    model_dir.mkdir(parents=True, exist_ok=True)
    (recon.write_text if text else recon.write_binary)(str(model_dir))


def write_colmap_scene(root: Path, n: int = 6, w: int = 32, h: int = 24, text: bool = True) -> Path:
    """A small COLMAP scene: sparse/0, images/img_<i>.png (RGB), masks/img_<i>.png."""
    cams = ring_cameras(n, w, h)
    names = [f"img_{i}.png" for i in range(n)]
    for i, name in enumerate(names):
        img = disk_rgba(w, h, seed=i)
        write_png(root / "images" / name, img[..., :3])
        write_png(root / "masks" / name, img[..., 3])
    write_colmap_model(root / "sparse" / "0", cams, names, text=text)
    return root


def ball_masks(cams: list[Camera], centre: np.ndarray, radius: float) -> list[np.ndarray]:
    """Bool [H,W] silhouettes of a ball (exact: a pixel ray passes within ``radius`` of ``centre``)."""
    out = []
    for cam in cams:
        rows, cols = np.mgrid[: cam.height, : cam.width]
        pix = np.stack([cols + 0.5, rows + 0.5, np.ones_like(cols)], -1).reshape(-1, 3).astype(float)
        rays = pix @ np.linalg.inv(cam.K).T @ cam.world_to_cam[:3, :3]  # world directions
        rays /= np.linalg.norm(rays, axis=1, keepdims=True)
        to_c = centre - cam.center
        dist = np.linalg.norm(to_c - (rays @ to_c)[:, None] * rays, axis=1)
        out.append((dist < radius).reshape(cam.height, cam.width))
    return out
