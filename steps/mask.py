"""mask: one object mask per training view.

``method``: ``provided`` (the scene's mask files or image alpha, validated), ``grabcut`` (OpenCV GrabCut
seeded from the image border), ``u2netp`` (the auto masks: the u2netp salient-object model from the
weights cache and the post-processing of go_core.scene.auto_mask, with the ``auto_*`` params), ``onnx``
(a salient-object ONNX model from ``onnx_model``, a local path), or ``auto``: provided when every training
view has a mask, else onnx when ``onnx_model`` is set, else u2netp when it is in the weights cache, else
grabcut (with a warning that says how to fetch u2netp). ``object_box`` (``x0,y0,x1,y1@PHOTO``, any photo
of the scene) tells u2netp where the object is (go_core.scene.object_hint). With ``auto_vote`` and at
least 8 posed views, u2netp masks every view and keeps what ``auto_vote`` of the views agree on in 3D
(docs/photo_masks.md). ``binary_edges: smooth`` replaces a provided mask that holds only 0 and 1 by each
outline pixel's estimated coverage (go_core.scene.mask_edges; ``edges: smoothed`` in its view's record).
The method used per view is recorded (``ctx.record(method=..., views=[...])``).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from go_core import artifacts as art
from go_core.errors import PipelineError, SceneError
from go_core.scene.auto_mask import VOTE_MIN_VIEWS
from go_core.scene.mask_edges import is_binary, smooth_binary_edges
from go_core.scene.masking import OnnxSegmenter, grabcut_mask, mask_stats, validate_mask

if TYPE_CHECKING:
    from go_pipeline.steps.params import MaskParams

METHODS = ("auto", "provided", "grabcut", "onnx", "u2netp")


def _choose(method: str, have_all: bool, onnx_model: str, log) -> str:
    """The method ``auto`` stands for here (see the module docstring)."""
    if method != "auto":
        return method
    if have_all:
        return "provided"
    if onnx_model:
        return "onnx"
    from go_core.io.weights_cache import FETCH_COMMAND
    from go_core.scene.salient_weights import u2netp_path

    if u2netp_path().is_file():
        return "u2netp"
    log.warning("auto masks: u2netp is not in the weights cache (%s); GrabCut instead. `%s` gets it",
                u2netp_path(), FETCH_COMMAND)  # fmt: skip
    return "grabcut"


def _masker(method: str, params: MaskParams, scene):
    """A function view -> mask for the computed methods (None for ``provided``)."""
    if method == "grabcut":
        return lambda i, v: grabcut_mask(v.image, params.grabcut_iterations, params.grabcut_border)
    if method == "onnx":
        if not params.onnx_model:
            raise PipelineError("mask.method=onnx needs mask.onnx_model (a local .onnx path)")
        segmenter = OnnxSegmenter(Path(params.onnx_model), params.onnx_normalization)
        return lambda i, v: segmenter(v.image)
    if method == "u2netp":
        return _auto_masker(params, scene)
    return None


def _auto_masker(params: MaskParams, scene):
    """u2netp masks; with ``auto_vote`` and at least VOTE_MIN_VIEWS posed views (training and test), the
    masks of all views made consistent through the poses (go_core.scene.auto_mask.hull_vote_masks)."""
    from go_core.scene.auto_mask import AutoMaskSettings, auto_mask, hull_vote_masks, load_segmenter
    from go_core.scene.object_hint import parse_object_box

    segmenter = load_segmenter()
    settings = AutoMaskSettings(params.auto_threshold, params.auto_crop_margin, refine=params.auto_refine)
    hint = parse_object_box(params.object_box) if params.object_box else None
    views = scene.train + scene.test
    boxes = _hint_boxes(scene, hint, views)
    if params.auto_vote <= 0 or len(views) < VOTE_MIN_VIEWS:
        return lambda i, v: auto_mask(v.image, segmenter, settings, boxes[i])
    masks = [auto_mask(v.image, segmenter, settings, b) for v, b in zip(views, boxes, strict=True)]
    voted = hull_vote_masks(masks, [v.camera for v in views], params.auto_vote)
    return lambda i, v: voted[i]


def _hint_boxes(scene, hint, views: list) -> list:
    """The object box of each of ``views`` (None without a hint), from the box drawn on one photo."""
    if hint is None:
        return [None] * len(views)
    from go_core.scene.auto_mask import carry_box

    every = scene.train + scene.test
    found = [v for v in every if hint.matches(v.name) or hint.matches(str(v.source or ""))]
    if not found:
        raise SceneError(f"mask.object_box names photo {hint.photo!r}, which is not a view of this scene")
    return carry_box(hint, found[0].image.shape[:2], [v.image.shape[:2] for v in views])


def run(ctx, inputs: dict[str, Path], params: MaskParams) -> None:
    scene = art.read_scene(inputs["scene"])
    views = scene.train
    have_all = all(v.mask is not None for v in views)
    method = _choose(params.method, have_all, params.onnx_model, ctx.log)
    if method == "provided" and not have_all:
        missing = [v.name for v in views if v.mask is None]
        raise SceneError(f"mask.method=provided but views {missing} have no mask file or alpha channel")
    masker = _masker(method, params, scene)

    masks, info = [], []
    bar = ctx.progress(len(views), "masks")
    for i, v in enumerate(views):
        label = str(v.source or v.name)
        edges = None
        if masker is None:
            m = v.mask
            validate_mask(m, v.image.shape[:2], label)
            if params.binary_edges == "smooth" and is_binary(m):
                m, edges = smooth_binary_edges(m), "smoothed"
        else:
            m = masker(i, v)
        if float((m > 0.5).mean()) == 0.0:
            raise SceneError(f"the {method} mask is empty: no object found", path=label)
        masks.append(m)
        info.append(
            {"view": v.name, "method": method, **mask_stats(m), **({"edges": edges} if edges else {})}
        )
        bar.advance()
    bar.close()
    art.write_masks(ctx.out_dir, masks)
    voted = method == "u2netp" and params.auto_vote > 0 and len(scene.train + scene.test) >= VOTE_MIN_VIEWS
    summary = {"method": method, "onnx_model": params.onnx_model if method == "onnx" else None,
               "object_box": params.object_box or None,
               "vote_views": len(scene.train + scene.test) if voted else 0, "views": info}  # fmt: skip
    art.write_json(ctx.out_dir, art.MASK_INFO, summary)
    ctx.record(method=method, views=len(masks), foreground=[i["foreground_fraction"] for i in info])
