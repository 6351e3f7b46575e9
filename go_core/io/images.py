"""Image files through OpenImageIO: read 8/16-bit PNG, JPEG, TIFF and EXR into float32, write 8-bit PNG.

Conventions (every reader in go_core relies on them):
* ``read_image`` returns float32 ``[H, W, C]`` with the file's channel count C (1-4). Integer files are
  scaled to [0, 1] (``value / 255`` or ``value / 65535``, computed in float32 so 8-bit data round-trips
  exactly). Float files (EXR, float TIFF) keep their values: they are linear and may exceed 1; nothing is
  tone-mapped or clipped.
* Alpha is returned straight (unassociated). PNG stores straight alpha, and OpenImageIO would premultiply it
  on read unless told not to, so files are opened with ``oiio:UnassociatedAlpha=1``. EXR stores
  premultiplied colour: it is divided by alpha where alpha > 0.
* Any failure (missing file, not an image, truncated data) raises ``ImageReadError`` naming the file.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from go_core.errors import SceneError
from go_core.io.atomic import atomic_write

# Extensions tried, in order, when a scene names an image without one (NeRF-synthetic ``file_path``).
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".exr", ".tif", ".tiff", ".PNG", ".JPG", ".JPEG", ".EXR")


class ImageReadError(SceneError):
    """An image file is missing or cannot be decoded."""


class ImageWriteError(SceneError):
    """An image file could not be written."""


def _one_line(text: str) -> str:
    return "; ".join(part.strip() for part in str(text).splitlines() if part.strip())


def _oiio():
    import OpenImageIO as oiio

    return oiio


def _open(path: Path):
    oiio = _oiio()
    if not path.is_file():
        raise ImageReadError("image file not found", path=path)
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)
    inp = oiio.ImageInput.open(str(path), config)
    if inp is None:
        reason = _one_line(oiio.geterror()) or "unknown format"
        raise ImageReadError(f"unreadable image ({reason})", path=path)
    return inp


def image_size(path: str | Path) -> tuple[int, int, int]:
    """(width, height, channels) from the file header, without decoding pixels."""
    path = Path(path)
    inp = _open(path)
    try:
        spec = inp.spec()
        return int(spec.width), int(spec.height), int(spec.nchannels)
    finally:
        inp.close()


def read_image(path: str | Path) -> np.ndarray:
    """Float32 ``[H, W, C]`` pixels of an image file (see the module docstring for scaling and alpha)."""
    oiio = _oiio()
    path = Path(path)
    inp = _open(path)
    try:
        spec = inp.spec()
        native = spec.format
        basetype = native.basetype
        integer = basetype in (oiio.UINT8, oiio.UINT16, oiio.INT8, oiio.INT16, oiio.UINT32, oiio.INT32)
        fmt = native if integer else oiio.FLOAT
        pixels = inp.read_image(0, 0, 0, spec.nchannels, fmt)
        if pixels is None or not isinstance(pixels, np.ndarray):
            err = _one_line(inp.geterror() or oiio.geterror())
            raise ImageReadError(f"unreadable image data ({err})", path=path)
        alpha_channel = int(spec.alpha_channel)
        file_format = inp.format_name()
    except ImageReadError:
        raise
    except Exception as exc:  # OIIO raises plain exceptions on truncated/corrupt data
        raise ImageReadError(f"unreadable image data ({_one_line(exc)})", path=path) from exc
    finally:
        inp.close()
    if pixels.ndim == 2:
        pixels = pixels[..., None]
    if pixels.shape[:2] != (spec.height, spec.width):
        got = f"{pixels.shape[1]}x{pixels.shape[0]}"
        raise ImageReadError(f"truncated image data ({got}, header {spec.width}x{spec.height})", path)
    if pixels.dtype == np.uint8:
        out = pixels.astype(np.float32) / np.float32(255.0)
    elif pixels.dtype == np.uint16:
        out = pixels.astype(np.float32) / np.float32(65535.0)
    elif np.issubdtype(pixels.dtype, np.integer):
        out = pixels.astype(np.float32) / np.float32(np.iinfo(pixels.dtype).max)
    else:
        out = pixels.astype(np.float32)
        if file_format == "openexr" and 0 <= alpha_channel < out.shape[2]:
            a = out[..., alpha_channel : alpha_channel + 1]
            colour = [c for c in range(out.shape[2]) if c != alpha_channel]
            safe = np.where(a > 0, a, 1.0)
            out[..., colour] = np.where(a > 0, out[..., colour] / safe, out[..., colour])
    return np.ascontiguousarray(out)


def split_rgb_alpha(pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """(RGB float32 [H, W, 3], alpha [H, W] or None) from 1-4 channel pixels (grey is replicated)."""
    c = pixels.shape[2]
    if c == 1:
        return np.repeat(pixels, 3, axis=2), None
    if c == 2:
        return np.repeat(pixels[..., :1], 3, axis=2), np.ascontiguousarray(pixels[..., 1])
    if c == 3:
        return pixels, None
    return np.ascontiguousarray(pixels[..., :3]), np.ascontiguousarray(pixels[..., 3])


def read_mask(path: str | Path) -> np.ndarray:
    """A mask file as float32 [H, W] in [0, 1]: the single/grey channel, the mean of RGB for colour files,
    or the alpha channel of a grey+alpha/RGBA file whose colour is constant (a cut-out saved as a mask)."""
    pixels = read_image(path)
    c = pixels.shape[2]
    if c == 1:
        m = pixels[..., 0]
    elif c in (2, 4):
        colour = pixels[..., : c - 1]
        m = pixels[..., c - 1] if float(colour.max() - colour.min()) == 0.0 else colour.mean(axis=2)
    else:
        m = pixels[..., :3].mean(axis=2)
    return np.ascontiguousarray(np.clip(m, 0.0, 1.0).astype(np.float32))


def to_uint8(image) -> np.ndarray:
    """Float [0, 1] (numpy or torch) → uint8, the one rounding rule of go-pipeline: round half up,
    ``floor(clip(x, 0, 1) · 255 + 0.5)``, in the input's float precision. uint8 passes through."""
    a = image.detach().cpu().numpy() if hasattr(image, "detach") else np.asarray(image)
    if a.dtype == np.uint8:
        return a
    if not np.issubdtype(a.dtype, np.floating):
        a = a.astype(np.float32)
    return (np.clip(a, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def composite(image, mask, background: float = 1.0):
    """RGB [H,W,3] over a constant background (white by default: the paper's protocol) with its
    fractional mask [H,W]: ``image·m + background·(1 − m)``; unchanged without a mask. numpy arrays come back
    as float32, torch tensors stay tensors."""
    if mask is None:
        return image if hasattr(image, "detach") else np.asarray(image, np.float32)
    if hasattr(image, "detach"):
        m = mask[..., None]
        return image * m + background * (1.0 - m)
    a = np.asarray(mask, np.float32)[..., None]
    return (np.asarray(image, np.float32) * a + np.float32(background) * (1.0 - a)).astype(np.float32)


def thumbnail(image, size: int) -> np.ndarray:
    """uint8 [h,w,3] no larger than ``size`` on its longest side (bilinear; never enlarged)."""
    from PIL import Image

    a = to_uint8(image)
    h, w = a.shape[:2]
    f = min(1.0, size / max(h, w))
    return np.asarray(Image.fromarray(a).resize((max(1, round(w * f)), max(1, round(h * f))), Image.BILINEAR))


def write_png(path: str | Path, image: np.ndarray) -> Path:
    """Write an 8-bit PNG atomically. ``image``: [H, W], [H, W, C] (C = 1-4) float in [0, 1] or uint8;
    a 4th channel is written as straight alpha."""
    oiio = _oiio()
    path = Path(path)
    data = to_uint8(image)
    if data.ndim == 2:
        data = data[..., None]
    if data.ndim != 3 or data.shape[2] not in (1, 2, 3, 4):
        raise ImageWriteError(f"cannot write an image of shape {tuple(np.shape(image))} as PNG", path=path)
    data = np.ascontiguousarray(data)
    h, w, c = data.shape

    def write(tmp: Path) -> None:
        out = oiio.ImageOutput.create("png")
        if out is None:
            raise ImageWriteError(f"no PNG writer ({oiio.geterror()})", path=path)
        spec = oiio.ImageSpec(w, h, c, "uint8")
        if c in (2, 4):
            spec.alpha_channel = c - 1
            spec.attribute("oiio:UnassociatedAlpha", 1)
        if not out.open(str(tmp), spec) or not out.write_image(data):
            err = out.geterror()
            out.close()
            raise ImageWriteError(f"cannot write PNG ({_one_line(err)})", path=path)
        out.close()

    return atomic_write(path, write)
