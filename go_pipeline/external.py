"""What a step reads besides its upstream artifacts, for its cache key: the versions of the libraries that
change results, the model files its params name, and the LPIPS weights in the shared cache.

* Libraries: ``DEPENDENCIES`` (from package metadata; nothing is imported).
* Model files: every set string param named ``*_path``, and every ``*_model`` param spelled as a path
  (e.g. ``mask.onnx_model``, ``depth.model_path``, ``weights.sd15_path``): the content hash of the file,
  or of every file of the folder. Hashes are remembered by (device, inode, size, mtime, ctime) in the work
  dir's hash cache, so a multi-GB model is read once, and an edited one (even at the same path) changes
  the key.
* LPIPS weights: steps with an ``lpips_net``/``lpips_nets`` param get the hash of those nets' safetensors
  files in ``$GO_PIPELINE_CACHE/lpips`` (``absent`` when not fetched: fetching them later reruns the step).
* Cached models: a ``salient_model`` param (``mask.salient_model: u2netp``) gets the hash of that model's
  file in the weights cache (``absent`` when not fetched: ``mask.method: auto`` then falls back to GrabCut,
  and fetching u2netp later reruns the step).
"""

from __future__ import annotations

import os
from functools import lru_cache
from importlib import metadata
from pathlib import Path
from typing import Any

from go_core.io.weights_cache import lpips_weights_file
from go_pipeline.hashing import FileHashCache, combine_file_hashes, folder_hashes

DEPENDENCIES = ("torch", "numpy", "pycolmap", "opencv-contrib-python-headless")
MODEL_PARAM_SUFFIXES = ("_path", "_model")
LPIPS_PARAMS = ("lpips_net", "lpips_nets")
CACHED_MODEL_PARAMS = ("salient_model",)


@lru_cache(maxsize=1)
def dependency_versions() -> dict[str, str]:
    """Installed versions of ``DEPENDENCIES`` ("absent" for one that is not installed)."""
    found: dict[str, str] = {}
    for name in DEPENDENCIES:
        try:
            found[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            found[name] = "absent"
    return found


def is_model_param(name: str, value: Any) -> bool:
    """A set ``*_path`` param, or a ``*_model`` param whose value is spelled as a path (``mask.onnx_model``
    is a file; ``repair.compact_model: realesr-animevideov3-x4`` is a name, left to its step)."""
    if not isinstance(value, str) or not value.strip():
        return False
    if name.endswith("_path"):
        return True
    return name.endswith("_model") and ("/" in value or os.sep in value or bool(Path(value).suffix))


def path_hash(path: Path, cache: FileHashCache | None) -> str:
    """Content hash of a file, or of a folder's files (names + bytes); ``missing`` when neither exists
    (the step reports that itself)."""
    if path.is_file():
        return cache.file_hash(path) if cache is not None else folder_hashes(path.parent)[path.name]
    if path.is_dir():
        return combine_file_hashes(folder_hashes(path, cache=cache))
    return "missing"


def cached_model_file(name: str) -> Path | None:
    """The weights-cache file of a model named by a ``CACHED_MODEL_PARAMS`` param (None: unknown name)."""
    from go_core.scene.salient_weights import u2netp_path

    return {"u2netp": u2netp_path()}.get(name)


def lpips_weight_hashes(nets: list[str], cache: FileHashCache | None) -> dict[str, str]:
    hashes = {}
    for net in sorted(set(nets)):
        path = lpips_weights_file(net)
        hashes[net] = path_hash(path, cache) if path.is_file() else "absent"
    return hashes


def external_inputs(params: dict[str, Any], cache: FileHashCache | None) -> dict[str, Any]:
    """The part of a step's cache key that lives outside the work dir (see the module docstring)."""
    files = {
        name: path_hash(Path(value).expanduser(), cache)
        for name, value in sorted(params.items())
        if is_model_param(name, value)
    }
    result: dict[str, Any] = {"libraries": dependency_versions()}
    if files:
        result["model_files"] = files
    nets: list[str] = []
    for name in LPIPS_PARAMS:
        value = params.get(name)
        if isinstance(value, str) and value:
            nets.append(value)
        elif isinstance(value, list):
            nets.extend(str(v) for v in value)
    if nets:
        result["lpips_weights"] = lpips_weight_hashes(nets, cache)
    cached = {}
    for name in CACHED_MODEL_PARAMS:
        value = params.get(name)
        path = cached_model_file(value) if isinstance(value, str) else None
        if path is not None:
            cached[value] = path_hash(path, cache) if path.is_file() else "absent"
    if cached:
        result["cached_models"] = cached
    return result


def describe_external_changes(old: dict[str, Any] | None, new: dict[str, Any]) -> list[str]:
    """One reason per changed item, for ``status``."""
    if old is None:
        return []
    reasons = []
    what = {"libraries": "library", "model_files": "model file", "lpips_weights": "LPIPS weights",
            "cached_models": "cached model"}  # fmt: skip
    for group in what:
        a, b = old.get(group) or {}, new.get(group) or {}
        for item in sorted(set(a) | set(b)):
            if a.get(item) != b.get(item):
                reasons.append(f"{what[group]} {item} changed")
    return reasons
