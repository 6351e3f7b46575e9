"""The ``scene`` step: read the scene folder, validate it, choose the training views, downscale, and write
the artifact every downstream step reads (``go_core.scene.artifact``: ``scene.json`` + ``views.npz``)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from go_core import artifacts as art
from go_core.errors import SceneError
from go_core.scene.loader import load_scene

if TYPE_CHECKING:
    from go_pipeline.steps.params import SceneParams


def run(ctx, inputs: dict[str, Path], params: SceneParams) -> None:
    """``inputs["folder"]`` is the raw scene folder (``folder: "@scene"`` in pipeline.yaml)."""
    views, max_size = params.views, params.max_size
    scene = load_scene(inputs["folder"], views=views, max_size=max_size)
    manifest = art.write_scene(ctx.out_dir, scene, views_requested=views, max_size=max_size)
    from go_pipeline.manifest import schema_problems

    problems = schema_problems("scene_manifest", manifest)
    if problems:  # a bug, not bad input: the artifact must never be marked complete
        path = art.SCENE_INFO.path(ctx.out_dir)
        raise SceneError(f"does not match scene_manifest.schema.json: {problems[0]}", path)
    if 0 < max_size < scene.original_max_side:
        ctx.log.warning(
            "images up to %d px on their longest side were downscaled to %d px (scene.max_size; "
            "--set scene.max_size=0 keeps the full resolution: slower, and memory grows with the pixels)",
            scene.original_max_side,
            max_size,
        )
    sizes = sorted({f"{c['width']}x{c['height']}" for c in manifest["train"] + manifest["test"]})
    ctx.log.info(
        "scene: %s, %d train + %d test views, %s (%s)",
        scene.format,
        len(scene.train),
        len(scene.test),
        ", ".join(sizes),
        scene.split_source,
    )
    ctx.record(
        format=scene.format,
        train_views=[v.name for v in scene.train],
        test_views=len(scene.test),
        resolutions=sizes,
        split_source=scene.split_source,
        downscaled_from=scene.original_max_side if 0 < max_size < scene.original_max_side else None,
        masks=sum(v.mask is not None for v in scene.train + scene.test),
    )
