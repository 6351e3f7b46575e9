"""Step artifact manifests: build one, check it against data_schema/step_manifest.schema.json."""

from __future__ import annotations

import datetime as dt
import json
import platform
import sys
from functools import lru_cache
from importlib import metadata
from pathlib import Path
from typing import Any

SCHEMA_ID = "go-pipeline/step-manifest"
SCHEMA_VERSION = 1
_LIBRARIES = (
    "go-pipeline",
    "torch",
    "numpy",
    "gsplat",
    "diffusers",
    "peft",
    "transformers",
    "pycolmap",
    "opencv-contrib-python-headless",
    "OpenImageIO",
    "scipy",
    "scikit-image",
)


def utc_now() -> str:
    return dt.datetime.now(dt.timezone.utc).isoformat(timespec="milliseconds").replace("+00:00", "Z")


@lru_cache(maxsize=1)
def library_versions() -> dict[str, str]:
    """Installed versions (from package metadata: nothing is imported)."""
    versions = {"python": platform.python_version()}
    for name in _LIBRARIES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
    return versions


def build_manifest(
    *,
    step: str,
    key: str,
    version: str | None,
    code: dict[str, str],
    seed: int,
    params: dict[str, Any],
    inputs: dict[str, dict[str, Any]],
    outputs: dict[str, str],
    output_sizes: dict[str, int],
    content_hash: str,
    wall_s: float,
    cpu_s: float,
    peak_mem_mb: float,
    device: str,
    started: str,
    finished: str,
    record: dict[str, Any],
    function: str,
    external: dict[str, Any] | None = None,
) -> dict[str, Any]:
    return {
        "schema": SCHEMA_ID,
        "schema_version": SCHEMA_VERSION,
        "step": step,
        "key": key,
        "version": version,
        "code": code,
        "function": function,
        "external": external or {},
        "seed": int(seed),
        "params": params,
        "inputs": inputs,
        "outputs": outputs,
        "output_sizes": output_sizes,
        "content_hash": content_hash,
        "wall_s": round(float(wall_s), 4),
        "cpu_s": round(float(cpu_s), 4),
        "peak_mem_mb": round(float(peak_mem_mb), 2),
        "device": device,
        "libraries": library_versions(),
        "platform": {
            "system": platform.system(),
            "machine": platform.machine(),
            "executable": sys.executable,
        },
        "started": started,
        "finished": finished,
        "record": record,
    }


@lru_cache(maxsize=4)
def _validator(name: str):
    import jsonschema

    from go_pipeline.resources import schema_path

    schema = json.loads(schema_path(name).read_text(encoding="utf-8"))
    cls = jsonschema.validators.validator_for(schema)
    cls.check_schema(schema)
    return cls(schema)


def schema_problems(name: str, instance: Any) -> list[str]:
    """Every violation of data_schema/<name>.schema.json, as 'at <json path>: <message>' lines."""
    errors = sorted(_validator(name).iter_errors(instance), key=lambda e: list(e.absolute_path))
    return [f"at {'/'.join(map(str, e.absolute_path)) or '(root)'}: {e.message}" for e in errors]


def check_manifest(manifest: dict[str, Any], path: Path | str) -> None:
    from go_core.errors import GoError

    problems = schema_problems("step_manifest", manifest)
    if problems:
        raise GoError(f"manifest does not match step_manifest.schema.json: {problems[0]}", path)
