"""Depth prior: a tiny randomly initialised DPT saved to a local folder, loaded and run like a real one."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from go_core.coarse.depth_prior import DepthEstimator, load_depth_priors, save_depth_priors
from go_core.errors import MissingWeightsError
from go_pipeline.pipeline import step_params

pytestmark = pytest.mark.usefixtures("single_thread")  # small tensors: one thread is faster


@pytest.fixture(scope="module")
def tiny_dpt(tmp_path_factory):
    from transformers import DPTConfig, DPTForDepthEstimation, DPTImageProcessor

    torch.manual_seed(0)
    cfg = DPTConfig(
        hidden_size=32,
        num_hidden_layers=4,
        num_attention_heads=2,
        intermediate_size=37,
        image_size=32,
        patch_size=8,
        backbone_out_indices=[0, 1, 2, 3],
        neck_hidden_sizes=[8, 8, 8, 8],
        fusion_hidden_size=16,
        reassemble_factors=[4, 2, 1, 0.5],
        head_in_index=-1,
        is_hybrid=False,
    )
    model = DPTForDepthEstimation(cfg).eval()
    folder = tmp_path_factory.mktemp("tiny_dpt")
    model.save_pretrained(folder)
    DPTImageProcessor(
        size={"height": 32, "width": 32}, keep_aspect_ratio=False, do_pad=False
    ).save_pretrained(folder)
    return folder, model


def test_tiny_dpt_gives_a_full_size_map_equal_to_the_direct_model_output(tiny_dpt):
    folder, model = tiny_dpt
    est = DepthEstimator(folder)
    assert est.name.startswith("dpt:")
    img = np.random.default_rng(0).random((40, 50, 3)).astype(np.float32)
    disp = est(img)
    assert disp.shape == (40, 50) and disp.dtype == np.float32 and np.isfinite(disp).all()
    # the same numbers as running the model by hand on the processor's input, then resizing
    inputs = est.processor(images=(img * 255 + 0.5).astype(np.uint8), return_tensors="pt")
    with torch.no_grad():
        ref = model(**inputs).predicted_depth[:, None]
        ref = torch.nn.functional.interpolate(ref, size=(40, 50), mode="bicubic", align_corners=False)[0, 0]
    assert np.allclose(disp, ref.numpy(), atol=1e-5)


def test_missing_model_is_a_clear_error(tmp_path):
    with pytest.raises(MissingWeightsError, match="config.json"):
        DepthEstimator(tmp_path)


def test_depth_artifact_round_trip_and_skip(tmp_path):
    maps = [np.random.default_rng(i).random((4, 6)).astype(np.float32) for i in range(2)]
    save_depth_priors(tmp_path, maps)
    back = load_depth_priors(tmp_path)
    assert all(np.array_equal(a, b) for a, b in zip(maps, back, strict=False))
    empty = tmp_path / "empty"
    save_depth_priors(empty, [])
    assert load_depth_priors(empty) is None and load_depth_priors(None) is None


def test_depth_step_with_a_local_model_writes_one_map_per_training_view(tiny_dpt, tmp_path):
    from go_pipeline.steps import depth
    from test_coarse_steps import Ctx, _scene

    folder, _ = tiny_dpt
    inputs = {"scene": _scene(tmp_path)}
    ctx = Ctx(tmp_path, "depth")
    depth.run(ctx, inputs, step_params(depth.__name__, {"model_path": str(folder)}))
    assert ctx.records["status"] == "ok" and ctx.records["kind"] == "disparity"
    maps = load_depth_priors(ctx.out_dir)
    assert len(maps) == 4 and all(m.shape == (32, 32) and np.isfinite(m).all() for m in maps)
