"""Where the packaged files live: pipeline.yaml, data_schema/ and the example scene.

A wheel carries copies in ``go_pipeline/_resources/`` (see setup.py); an editable install reads them from
the checkout (the repository top level, one folder above this package).
"""

from __future__ import annotations

from pathlib import Path

_PKG = Path(__file__).resolve().parent
_RESOURCES = _PKG / "_resources"
_CHECKOUT = _PKG.parent


def _in_checkout() -> bool:
    return (_CHECKOUT / "pyproject.toml").is_file() and (_CHECKOUT / "steps" / "_api.py").is_file()


def _find(name: str) -> Path:
    for base in (_CHECKOUT, _RESOURCES) if _in_checkout() else (_RESOURCES,):
        candidate = base / name
        if candidate.exists():
            return candidate
    raise FileNotFoundError(f"packaged resource {name} not found in {_CHECKOUT} or {_RESOURCES}")


def default_pipeline_path() -> Path:
    """The pipeline.yaml shipped with the package."""
    return _find("pipeline.yaml")


def schema_path(name: str) -> Path:
    """A JSON Schema of ``data_schema/``, e.g. ``schema_path("step_manifest")``."""
    return _find(f"data_schema/{name}.schema.json")


def example_scene_path() -> Path:
    """The built-in example scene (a copy of the CC BY 4.0 sample ``basket``; see its ATTRIBUTION.txt)."""
    return _PKG / "examples" / "basket"


def viewer_bundle_dir() -> Path:
    """The vendored splat viewer (three.js + Spark, built by js/build.mjs): viewer.min.js, viewer.json and
    the licences. Inside the package in both installs, so a wheel carries it."""
    return _RESOURCES / "viewer"
