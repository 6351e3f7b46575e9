"""mask: one object mask per training view.

``method``: ``provided`` (the scene's mask files or image alpha, validated), ``grabcut`` (OpenCV GrabCut
seeded from the image border), ``onnx`` (a salient-object ONNX model from ``onnx_model``, a local path), or
``auto``: provided when every training view has a mask, else onnx when ``onnx_model`` is set, else grabcut.
The method used per view is recorded (``ctx.record(method=..., views=[...])``).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from go_core import artifacts as art
from go_core.errors import PipelineError, SceneError
from go_core.scene.masking import OnnxSegmenter, grabcut_mask, mask_stats, validate_mask

if TYPE_CHECKING:
    from go_pipeline.steps.params import MaskParams

METHODS = ("auto", "provided", "grabcut", "onnx")


def run(ctx, inputs: dict[str, Path], params: MaskParams) -> None:
    method = params.method
    onnx_model = params.onnx_model
    scene = art.read_scene(inputs["scene"])
    views = scene.train
    have_all = all(v.mask is not None for v in views)
    if method == "auto":
        method = "provided" if have_all else ("onnx" if onnx_model else "grabcut")
    if method == "provided" and not have_all:
        missing = [v.name for v in views if v.mask is None]
        raise SceneError(f"mask.method=provided but views {missing} have no mask file or alpha channel")
    if method == "onnx" and not onnx_model:
        raise PipelineError("mask.method=onnx needs mask.onnx_model (a local .onnx path)")
    segmenter = OnnxSegmenter(Path(onnx_model), params.onnx_normalization) if method == "onnx" else None

    masks, info = [], []
    bar = ctx.progress(len(views), "masks")
    for v in views:
        label = str(v.source or v.name)
        if method == "provided":
            m = v.mask
            validate_mask(m, v.image.shape[:2], label)
        elif method == "grabcut":
            m = grabcut_mask(v.image, params.grabcut_iterations, params.grabcut_border)
        else:
            m = segmenter(v.image)
        if float((m > 0.5).mean()) == 0.0:
            raise SceneError(f"the {method} mask is empty: no object found", path=label)
        masks.append(m)
        info.append({"view": v.name, "method": method, **mask_stats(m)})
        bar.advance()
    bar.close()
    art.write_masks(ctx.out_dir, masks)
    summary = {"method": method, "onnx_model": onnx_model if method == "onnx" else None, "views": info}
    art.write_json(ctx.out_dir, art.MASK_INFO, summary)
    ctx.record(method=method, views=len(masks), foreground=[i["foreground_fraction"] for i in info])
