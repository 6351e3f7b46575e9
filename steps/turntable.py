"""turntable: an animated GIF orbiting the final model (repaired if available, else coarse) on the ellipse
fitted to the TRAINING cameras only, a contact-sheet PNG of evenly spaced frames, and ``camera_path.mp4``: a
video along a closed path through the training cameras (``path_frames`` frames between consecutive ones,
H.264, written bit-exactly so a rerun gives the same bytes)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch
from go_pipeline.steps._common import final_model

from go_core import artifacts as art
from go_core.gaussians import Gaussians
from go_core.io.atomic import atomic_write
from go_core.io.images import to_uint8
from go_core.render import render_camera
from go_core.render.trajectory import camera_path_cameras, contact_sheet, turntable_cameras

if TYPE_CHECKING:
    from go_pipeline.steps.params import TurntableParams


def render_frames(
    ctx, g: Gaussians, cams: list, bg: torch.Tensor, backend: str, what: str
) -> list[np.ndarray]:
    frames = []
    bar = ctx.progress(len(cams), what)
    with torch.no_grad():
        for cam in cams:
            out = render_camera(g, cam, background=bg, backend=backend)
            frames.append(to_uint8(out.rgb[0]))
            bar.advance()
    bar.close()
    return frames


def write_mp4(path: Path, frames: list[np.ndarray], fps: float) -> None:
    """H.264 MP4 (yuv420p, even sizes), one encoder thread and bit-exact flags: same frames, same bytes."""
    import imageio_ffmpeg

    h, w = frames[0].shape[:2]
    h2, w2 = h + h % 2, w + w % 2
    writer = imageio_ffmpeg.write_frames(
        str(path),
        (w2, h2),
        fps=fps,
        codec="libx264",
        pix_fmt_in="rgb24",
        pix_fmt_out="yuv420p",
        quality=None,
        macro_block_size=1,
        ffmpeg_log_level="error",
        output_params=[
            "-crf",
            "18",
            "-threads",
            "1",
            "-fflags",
            "+bitexact",
            "-flags:v",
            "+bitexact",
            "-map_metadata",
            "-1",
            "-f",
            "mp4",
        ],
    )
    writer.send(None)
    for f in frames:
        padded = np.pad(f, ((0, h2 - h), (0, w2 - w), (0, 0)), mode="edge")
        writer.send(np.ascontiguousarray(padded))
    writer.close()


def run(ctx, inputs: dict[str, Path], params: TurntableParams) -> None:
    import imageio.v3 as iio

    path_frames, max_size = params.path_frames, params.max_size
    g, source = final_model(inputs)
    train_cams, _ = art.read_scene_cameras(inputs["scene"])
    train_cams = art.read_fitted_cameras(inputs["coarse"], train_cams)  # the frame the model lives in
    cams = turntable_cameras(train_cams, params.frames, max_size)
    bg = torch.tensor(params.background, dtype=torch.float32)
    backend = params.backend
    frames = render_frames(ctx, g, cams, bg, backend, "turntable")
    fps = float(params.fps)
    atomic_write(
        art.TURNTABLE.path(ctx.out_dir),
        lambda p: iio.imwrite(p, np.stack(frames), extension=".gif", duration=1000.0 / fps, loop=0),
    )
    sheet = contact_sheet(frames, params.sheet_frames)
    atomic_write(art.CONTACT_SHEET.path(ctx.out_dir), lambda p: iio.imwrite(p, sheet, extension=".png"))
    path_cams = camera_path_cameras(train_cams, path_frames, max_size)
    video = render_frames(ctx, g, path_cams, bg, backend, "camera path video")
    atomic_write(art.CAMERA_PATH_VIDEO.path(ctx.out_dir), lambda p: write_mp4(p, video, fps))
    ctx.record(
        source=source, frames=len(frames), path_frames=len(video), size=[cams[0].width, cams[0].height]
    )
