"""``validate_scene``: check a scene folder and report what was found, or EVERY problem found.

Used by ``go-pipeline validate SCENE``: print ``report.summary()`` and exit non-zero unless ``report.ok``.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from go_core.scene.common import Problems
from go_core.scene.loader import read_scene_folder
from go_core.scene.types import Scene, View


@dataclass
class ValidationReport:
    """The outcome of ``validate_scene``: ``problems`` (one line each, "file: what is wrong") and, when the
    scene could be read, what it holds."""

    path: Path
    problems: list[str] = field(default_factory=list)
    scene: Scene | None = field(default=None, repr=False)
    photos: dict | None = None  # a folder of photos without poses (go_core.photos.scene.photo_folder_facts)

    @property
    def ok(self) -> bool:
        return not self.problems and (self.scene is not None or bool(self.photos))

    def facts(self) -> dict:
        """Format, view counts, resolutions, intrinsics and split source of the scene read (JSON-able)."""
        s = self.scene
        if s is None:
            return dict(self.photos or {})

        def resolutions(views: list[View]) -> dict[str, int]:
            return dict(Counter(f"{v.camera.width}x{v.camera.height}" for v in views))

        def fxfy(v: View) -> str:
            K = v.camera.K
            return f"fx={K[0, 0]:.2f} fy={K[1, 1]:.2f} cx={K[0, 2]:.2f} cy={K[1, 2]:.2f}"

        def intrinsics(views: list[View]) -> dict[str, int]:
            return dict(Counter(fxfy(v) for v in views))

        masked = sum(v.mask is not None for v in s.train + s.test)
        return {
            "format": s.format,
            "train_views": len(s.train),
            "test_views": len(s.test),
            "train_names": [v.name for v in s.train],
            "resolutions": resolutions(s.train + s.test),
            "intrinsics": intrinsics(s.train + s.test),
            "masks": f"{masked} of {len(s.train) + len(s.test)} views",
            "split_source": s.split_source,
        }

    def summary(self) -> str:
        """Human-readable text: what the scene holds when it is OK, else the list of problems."""
        if not self.ok:
            n = len(self.problems)
            lines = [f"{self.path}: {n} problem{'s' if n != 1 else ''} found"]
            lines += [f"  - {p}" for p in self.problems] or ["  - the scene could not be read"]
            return "\n".join(lines)
        f = self.facts()
        if self.photos:
            return "\n".join(
                [
                    f"{self.path}: OK (a folder of {f['photos']} photos without poses: {f['folder']})",
                    f"  sizes       : {', '.join(f['sizes'])}; {f['camera_groups']} camera(s), EXIF focal "
                    f"length in {f['exif_focal']}, turned by EXIF: {len(f['rotated_by_exif'])}",
                    "  a run will  : " + "; ".join(f["plan"]),
                ]
            )
        lines = [
            f"{self.path}: OK ({f['format']} scene)",
            f"  train views : {f['train_views']} ({', '.join(f['train_names'])})",
            f"  test views  : {f['test_views']}"
            if f["test_views"]
            else "  test views  : none (no test split: `eval` will fail; run with `--until turntable`)",
            f"  split       : {f['split_source']}",
            "  resolution  : " + ", ".join(f"{k} ({n} views)" for k, n in f["resolutions"].items()),
            "  intrinsics  : " + "; ".join(f"{k} ({n} views)" for k, n in f["intrinsics"].items()),
            f"  masks       : {f['masks']}",
        ]
        return "\n".join(lines)


def validate_scene(path: str | Path, views: int = 0, max_size: int = 0) -> ValidationReport:
    """Read the scene at ``path`` collecting every problem instead of stopping at the first."""
    from go_core.photos.folder import is_photo_folder

    problems = Problems(strict=False)
    if is_photo_folder(path):
        from go_core.photos.scene import photo_folder_facts

        facts = photo_folder_facts(path, views, problems)
        return ValidationReport(Path(path), problems.lines, None, facts)
    scene = read_scene_folder(path, views, max_size, problems)
    return ValidationReport(Path(path), problems.lines, scene)
