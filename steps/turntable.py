"""turntable: an animated GIF orbiting the final model (repaired if available, else coarse) on the ellipse
fitted to the TRAINING cameras only, and a contact-sheet PNG of evenly spaced frames."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from go_pipeline.steps._common import final_model_path

from go_core.gaussians import Gaussians
from go_core.io.atomic import atomic_write
from go_core.render import render_camera
from go_core.scene.artifact import load_scene_cameras
from go_core.trajectory import contact_sheet, turntable_cameras

VERSION = "1"


def run(ctx, inputs: dict[str, Path], params: dict) -> None:
    import imageio.v3 as iio

    path, source = final_model_path(inputs)
    g = Gaussians.load(path)
    train_cams, _ = load_scene_cameras(inputs["scene"])
    cams = turntable_cameras(train_cams, int(params.get("frames", 60)), int(params.get("max_size", 256)))
    bg = torch.tensor([float(x) for x in params.get("background", [1.0, 1.0, 1.0])], dtype=torch.float32)
    backend = str(params.get("backend", "auto"))
    frames = []
    bar = ctx.progress(len(cams), "turntable")
    with torch.no_grad():
        for cam in cams:
            out = render_camera(g, cam, background=bg, backend=backend)
            frames.append((out.rgb[0].clamp(0, 1).numpy() * 255.0 + 0.5).astype(np.uint8))
            bar.advance()
    bar.close()
    fps = float(params.get("fps", 20))
    atomic_write(
        ctx.out_dir / "turntable.gif",
        lambda p: iio.imwrite(p, np.stack(frames), extension=".gif", duration=1000.0 / fps, loop=0),
    )
    sheet = contact_sheet(frames, int(params.get("sheet_frames", 8)))
    atomic_write(ctx.out_dir / "contact_sheet.png", lambda p: iio.imwrite(p, sheet, extension=".png"))
    ctx.record(source=source, frames=len(frames), size=[cams[0].width, cams[0].height])
