"""The user's one hint for a whole capture: a box drawn once around the object on one photo.

Spelled ``x0,y0,x1,y1@PHOTO`` (``--object-box``, ``mask.object_box``) or written as ``object_box.json``
beside the photos: ``{"photo": "DSC_0007.jpg", "box": [x0, y0, x1, y1]}``. Coordinates are pixels of that
photo as stored in its file (x right, y down, x1/y1 exclusive), or fractions of its width/height when all
four are ≤ 1. PHOTO is the photo's file name or stem.

How the box reaches the other photos is ``go_core.scene.auto_mask``'s business (with or without camera poses).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from go_core.errors import SceneError

HINT_FILE = "object_box.json"


@dataclass(frozen=True)
class ObjectBox:
    """A box around the object on one photo (``photo``: its file name or stem)."""

    photo: str
    box: tuple[float, float, float, float]

    @property
    def fractional(self) -> bool:
        return all(0.0 <= v <= 1.0 for v in self.box)

    def pixels(self, width: int, height: int, file_size: tuple[int, int] | None = None) -> tuple[float, ...]:
        """The box in pixels of an image ``width`` × ``height`` showing the photo (``file_size``: the photo
        file's (width, height), when the image is a rescaled copy)."""
        x0, y0, x1, y1 = self.box
        if self.fractional:
            return x0 * width, y0 * height, x1 * width, y1 * height
        sx, sy = (width / file_size[0], height / file_size[1]) if file_size else (1.0, 1.0)
        return x0 * sx, y0 * sy, x1 * sx, y1 * sy

    def matches(self, name: str) -> bool:
        """Whether a view name or file name is this box's photo (by stem when either has no extension)."""
        a, b = Path(self.photo), Path(name)
        return a.name == b.name or a.stem == b.stem and (not a.suffix or not b.suffix or a.suffix == b.suffix)


def _check(photo: str, values: list, where: str) -> ObjectBox:
    if not photo:
        raise SceneError(f"object box {where}: name the photo the box is drawn on (x0,y0,x1,y1@PHOTO)")
    try:
        box = tuple(float(v) for v in values)
    except (TypeError, ValueError):
        raise SceneError(f"object box {where}: the corners must be numbers, got {values!r}") from None
    if len(box) != 4:
        raise SceneError(f"object box {where}: want 4 numbers x0,y0,x1,y1, got {len(box)}")
    x0, y0, x1, y1 = box
    if not (x1 > x0 >= 0 and y1 > y0 >= 0):
        raise SceneError(f"object box {where}: want 0 <= x0 < x1 and 0 <= y0 < y1, got {list(box)}")
    return ObjectBox(photo, box)  # type: ignore[arg-type]


def parse_object_box(text: str) -> ObjectBox:
    """``x0,y0,x1,y1@PHOTO`` → ObjectBox; a malformed spelling is one SceneError saying what is wrong."""
    corners, sep, photo = text.strip().partition("@")
    if not sep:
        raise SceneError(f"object box {text!r}: want x0,y0,x1,y1@PHOTO (the photo the box is drawn on)")
    return _check(photo.strip(), corners.split(","), repr(text))


def read_object_box(path: str | Path) -> ObjectBox:
    """An ``object_box.json`` file → ObjectBox (one SceneError naming the file when it is malformed)."""
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        photo, values = str(data["photo"]), data["box"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise SceneError(f'want {{"photo": NAME, "box": [x0, y0, x1, y1]}} ({exc})', path) from None
    return _check(photo, values if isinstance(values, list) else [values], str(path))


def find_object_box(folder: str | Path) -> ObjectBox | None:
    """The ``object_box.json`` beside the photos (in ``folder`` or its parent of ``images/``), or None."""
    folder = Path(folder)
    for candidate in (folder / HINT_FILE, folder.parent / HINT_FILE if folder.name == "images" else None):
        if candidate is not None and candidate.is_file():
            return read_object_box(candidate)
    return None
