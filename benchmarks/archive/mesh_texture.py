"""Vertex colours or a baked texture in ``model.glb`` (issue 35): what the exported mesh shows at the test
views. Each variant is written as the mesh step writes ``model.glb``, read back with trimesh and ray-cast
from every test camera (go_core.metrics.mesh_render, independent of the Gaussian renderer); PSNR against the
test photo on white (eval's protocol), over the whole image and inside the true mask.

Variants: ``vertex`` (the mesh step's mesh at its defaults: what ``model.glb`` held before), ``vertex_N``
(decimated to N faces, colours from the colour volume) and ``texture_N`` (decimated to N faces, unwrapped
by xatlas and baked from the final model's renders: the mesh step's own ``glb_mesh``, go_core.mesh.texture).
The final models are the repair artifacts of default runs (``--model SCENE=GAUSSIANS.npz``).

    python benchmarks/archive/mesh_texture.py --data ../shared/data/dev \\
        --model basket=W/basket/artifacts/repair/KEY/gaussians.npz --faces 20000 \\
        --out benchmarks/results/mesh_texture.json          # more scenes: --merge
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from _final_models import load_final  # benchmarks/ is on sys.path as a script
from _machine import code_version, cpu_name

from go_core.camera import fit_ellipse
from go_core.io.images import composite
from go_core.mesh.extract import fuse_gaussians, glb_mesh, surface
from go_core.mesh.files import read_glb_world, write_glb
from go_core.mesh.settings import MeshSettings
from go_core.mesh.surface import decimate
from go_core.metrics.mesh_render import render_mesh
from go_core.metrics.psnr import psnr


def score_glb(path: Path, ellipse, scene, supersample: int, pictures: list | None = None) -> dict:
    """Mean PSNR over the test views of the glb at ``path`` (whole image, inside the true mask); the first
    test view's render is appended to ``pictures`` when given."""
    mesh = read_glb_world(path, ellipse.normal, ellipse.target)
    whole, inside = [], []
    for view in scene.test:
        truth = torch.as_tensor(composite(view.image, view.mask))
        rgb, _ = render_mesh(mesh, view.camera, supersample)
        whole.append(psnr(torch.as_tensor(rgb), truth))
        inside.append(psnr(torch.as_tensor(rgb), truth, torch.as_tensor(view.mask > 0.5)))
        if pictures is not None and len(whole) == 1:
            pictures.append(rgb)
    return {
        "psnr": round(float(np.mean(whole)), 3),
        "psnr_in_mask": round(float(np.mean(inside)), 3),
        "faces": int(len(mesh.faces)),
        "bytes": path.stat().st_size,
        "megabytes": round(path.stat().st_size / 1e6, 2),
    }


def measure(scene_dir: Path, gaussians: Path, faces: list[int], texture_size: int, sharpness: list[float],
            supersample: int, picture: Path | None = None) -> dict:  # fmt: skip
    """One scene: each variant's glb scored (``score_glb``), with the texture's seconds and size."""
    final = load_final(scene_dir, gaussians)
    settings = MeshSettings()
    fused = fuse_gaussians(final.gaussians, final.cameras, final.box, settings, final.masks)
    mesh, _, _ = surface(fused, settings)
    variants, seconds = {"vertex": mesh}, {}
    for n in faces:
        small = decimate(mesh, n)
        small.colours = fused.colours_at(small.vertices)
        variants[f"vertex_{n}"] = small
        for k in sharpness:
            name = f"texture_{n}" + (f"_s{k:g}" if len(sharpness) > 1 else "")
            chosen = replace(settings, texture_size=texture_size, texture_faces=n, texture_sharpness=k)
            t0 = time.perf_counter()
            variants[name] = glb_mesh(fused, mesh, final.gaussians, final.cameras, chosen)  # the step's
            seconds[name] = round(time.perf_counter() - t0, 1)
    ellipse = fit_ellipse(final.cameras)
    out = {"gaussians": str(gaussians), "variants": {}}
    pictures = [composite(final.scene.test[0].image, final.scene.test[0].mask)]
    with tempfile.TemporaryDirectory() as tmp:
        for name, m in variants.items():
            path = write_glb(m, Path(tmp) / f"{name}.glb", ellipse.normal, ellipse.target)
            out["variants"][name] = score_glb(path, ellipse, final.scene, supersample, pictures)
            if name in seconds:
                out["variants"][name]["texture_seconds"] = seconds[name]
                out["variants"][name]["texture_size"] = [int(x) for x in variants[name].texture.shape[1::-1]]
            print(scene_dir.name, name, out["variants"][name], flush=True)
    if picture is not None:  # truth | each variant, first test view
        from PIL import Image

        from go_core.io.images import to_uint8

        picture.parent.mkdir(parents=True, exist_ok=True)
        Image.fromarray(to_uint8(np.concatenate(pictures, axis=1))).save(picture, quality=90)
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--model", nargs="+", required=True, help="SCENE=path/to/gaussians.npz")
    ap.add_argument("--faces", type=int, nargs="+", default=[20000])
    ap.add_argument("--texture-size", type=int, default=MeshSettings().texture_size)
    ap.add_argument("--sharpness", type=float, nargs="+", default=[MeshSettings().texture_sharpness])
    ap.add_argument("--supersample", type=int, default=2)
    ap.add_argument("--picture", type=Path, help="folder for SCENE_mesh_texture.jpg: truth | each variant")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--merge", action="store_true")
    args = ap.parse_args(argv)
    result = json.loads(args.out.read_text()) if args.merge else {}
    result.update(
        benchmark="mesh_texture",
        code=code_version(),
        machine=cpu_name(),
        settings={k: getattr(args, k) for k in ("faces", "texture_size", "sharpness", "supersample")},
    )
    scenes = result.setdefault("scenes", {})
    for item in args.model:
        name, _, path = item.partition("=")
        picture = None if args.picture is None else args.picture / f"{name}_mesh_texture.jpg"
        scenes[name] = measure(args.data / name, Path(path), args.faces, args.texture_size, args.sharpness,
                               args.supersample, picture)  # fmt: skip
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
