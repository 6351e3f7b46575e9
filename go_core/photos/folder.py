"""A folder of photos without poses: which files, how to read them, which camera took each.

* Photos: JPEG, PNG, TIFF, WebP (and HEIC/HEIF when the optional ``pillow-heif`` is installed) directly in
  the folder, or in its ``images/`` subfolder; names sorted, which is capture order for camera file names.
* Reading honours the EXIF orientation (the pixels are turned as a viewer shows them), so a portrait photo
  taken with a turned phone is upright. A photo with an alpha channel keeps it as its mask.
* Camera groups: photos that share make, model, focal length and (turned) size share intrinsics in SfM; the
  EXIF 35 mm-equivalent focal length gives the prior focal length in pixels (f35 / 43.27 mm × diagonal px).
* Problems (each one line naming the file): an unreadable or truncated photo, two photos with the same
  picture, fewer than ``MIN_PHOTOS`` photos.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from go_core.scene.common import Problems

PHOTO_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".webp", ".heic", ".heif")
HEIF_SUFFIXES = (".heic", ".heif")
MIN_PHOTOS = 8  # fewer cannot be posed reliably by SfM (4 photos 90° apart never were: issue 19)
FULL_FRAME_DIAGONAL_MM = 43.27  # the 35 mm-equivalent focal length is defined on this diagonal
_EXIF_ORIENTATION, _EXIF_MAKE, _EXIF_MODEL = 0x0112, 0x010F, 0x0110
_EXIF_IFD, _EXIF_FOCAL, _EXIF_FOCAL35 = 0x8769, 0x920A, 0xA405


@dataclass(frozen=True)
class PhotoFile:
    """One photo's file and header facts (no pixels)."""

    path: Path
    name: str  # file stem: the view name
    width: int  # after the EXIF orientation
    height: int
    orientation: int  # EXIF orientation tag (1: as stored)
    camera: str  # make + model ("" when unknown)
    focal_mm: float | None  # EXIF focal length
    focal35_mm: float | None  # EXIF 35 mm-equivalent focal length

    @property
    def group_key(self) -> tuple:
        return (self.camera, self.focal_mm, self.focal35_mm, self.width, self.height)

    def focal_px(self, long_side: int) -> float | None:
        """The EXIF focal length in pixels of the photo scaled to ``long_side`` (None: unknown)."""
        if not self.focal35_mm:
            return None
        s = long_side / max(self.width, self.height)
        return float(self.focal35_mm / FULL_FRAME_DIAGONAL_MM * np.hypot(self.width, self.height) * s)


def _register_heif() -> bool:
    try:
        from pillow_heif import register_heif_opener
    except ImportError:
        return False
    register_heif_opener()
    return True


def photo_dir(root: Path) -> Path | None:
    """``root/images`` when it holds photos, else ``root`` when it does, else None."""
    for folder in (root / "images", root):
        if folder.is_dir() and any(_is_photo(f) for f in folder.iterdir()):
            return folder
    return None


def is_photo_folder(root: str | Path) -> bool:
    """A folder of photos without poses: no scene format file (NeRF json, COLMAP sparse/), photos in it or
    in its ``images/``."""
    from go_core.scene.loader import detect_format

    root = Path(root)
    return root.is_dir() and detect_format(root) is None and photo_dir(root) is not None


def _is_photo(path: Path) -> bool:
    return path.is_file() and path.suffix.lower() in PHOTO_SUFFIXES and not path.name.startswith(".")


def photo_files(folder: Path) -> list[Path]:
    """The photos of ``folder``, sorted by name."""
    return sorted(f for f in folder.iterdir() if _is_photo(f))


def _exif_facts(img) -> tuple[int, str, float | None, float | None]:
    exif = img.getexif()
    sub = exif.get_ifd(_EXIF_IFD)

    def num(v) -> float | None:
        try:
            f = float(v)
        except (TypeError, ValueError, ZeroDivisionError):
            return None
        return f if np.isfinite(f) and f > 0 else None

    camera = " ".join(str(exif.get(t, "")).strip("\x00 ") for t in (_EXIF_MAKE, _EXIF_MODEL)).strip()
    orientation = int(exif.get(_EXIF_ORIENTATION, 1) or 1)
    return orientation, camera, num(sub.get(_EXIF_FOCAL)), num(sub.get(_EXIF_FOCAL35))


def scan_photo(path: Path, problems: Problems) -> PhotoFile | None:
    """Header facts of one photo; an unreadable file is a problem (None)."""
    from PIL import Image, UnidentifiedImageError

    if path.suffix.lower() in HEIF_SUFFIXES and not _register_heif():
        problems.add("HEIC/HEIF photo: install pillow-heif (pip install pillow-heif) to read it", path)
        return None
    try:
        with Image.open(path) as img:
            orientation, camera, focal, focal35 = _exif_facts(img)
            w, h = img.size
    except (OSError, UnidentifiedImageError, ValueError, SyntaxError) as exc:
        problems.add(f"unreadable photo ({_one_line(exc)})", path)
        return None
    if orientation in (5, 6, 7, 8):  # turned by 90°: width and height swap
        w, h = h, w
    return PhotoFile(path, path.stem, w, h, orientation, camera, focal, focal35)


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def read_photo(photo: PhotoFile, long_side: int = 0) -> tuple[np.ndarray, np.ndarray | None]:
    """(RGB float32 [H, W, 3], alpha float32 [H, W] or None), upright (EXIF), scaled with an area filter so
    that the long side is at most ``long_side`` (0: as stored). Raises ``ImageReadError`` on a truncated
    or corrupt file, naming it."""
    import cv2
    from PIL import Image, ImageOps

    from go_core.io.images import ImageReadError

    if photo.path.suffix.lower() in HEIF_SUFFIXES:
        _register_heif()
    try:
        with Image.open(photo.path) as img:
            img.load()  # decodes every byte: a truncated JPEG raises here
            img = ImageOps.exif_transpose(img)
            has_alpha = img.mode in ("RGBA", "LA", "PA") or "transparency" in img.info
            img = img.convert("RGBA" if has_alpha else "RGB")
            a = np.asarray(img, np.float32) / np.float32(255.0)
    except (OSError, ValueError, SyntaxError) as exc:
        raise ImageReadError(f"unreadable photo data ({_one_line(exc)})", path=photo.path) from None
    h, w = a.shape[:2]
    if long_side and max(w, h) > long_side:
        s = long_side / max(w, h)
        a = cv2.resize(a, (max(1, round(w * s)), max(1, round(h * s))), interpolation=cv2.INTER_AREA)
    rgb = np.ascontiguousarray(a[..., :3])
    alpha = np.ascontiguousarray(a[..., 3]) if a.shape[2] == 4 else None
    if alpha is not None and float(alpha.min()) >= 1.0:
        alpha = None  # an opaque alpha channel carries no mask
    return rgb, alpha


def camera_groups(photos: list[PhotoFile]) -> list[int]:
    """Per photo, the index of its camera group (first appearance order)."""
    keys: dict[tuple, int] = {}
    return [keys.setdefault(p.group_key, len(keys)) for p in photos]


def duplicate_pairs(names: list[str], images: list[np.ndarray], tol: float = 1.0 / 255.0) -> list[tuple]:
    """Pairs of names whose pictures are the same (mean absolute difference of 32×32 grey thumbnails
    below ``tol``): the same photo twice, or a copy saved again."""
    import cv2

    thumbs = []
    for img in images:
        grey = cv2.cvtColor(np.asarray(img, np.float32), cv2.COLOR_RGB2GRAY)
        thumbs.append(cv2.resize(grey, (32, 32), interpolation=cv2.INTER_AREA))
    out = []
    for i in range(len(thumbs)):
        for j in range(i + 1, len(thumbs)):
            if thumbs[i].shape == thumbs[j].shape and float(np.abs(thumbs[i] - thumbs[j]).mean()) < tol:
                out.append((names[i], names[j]))
    return out
