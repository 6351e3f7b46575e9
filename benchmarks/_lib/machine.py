"""What machine and code a benchmark ran on (shared by the scripts, which run as `python benchmarks/X.py`
and import it as ``_lib.machine``)."""

from __future__ import annotations

import platform
import subprocess
from pathlib import Path


def cpu_name() -> str:
    """The CPU model from /proc/cpuinfo with its family and model numbers (VMs often show only a brand
    name, e.g. "AMD EPYC", for CPUs of different speeds), else what the platform module knows."""
    fields: dict[str, str] = {}
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            key, _, value = line.partition(":")
            fields.setdefault(key.strip(), value.strip())
    except OSError:
        pass
    if "model name" not in fields:
        return platform.processor() or platform.machine()
    family, model = fields.get("cpu family", "?"), fields.get("model", "?")
    return f"{fields['model name']} (family {family}, model {model})"


def code_version() -> str:
    """The repository commit a result was made with (``+dirty`` when the work tree has changes)."""
    repo = Path(__file__).resolve().parents[2]
    try:
        head = subprocess.run(["git", "-C", str(repo), "rev-parse", "HEAD"], capture_output=True, text=True)
        dirty = subprocess.run(
            ["git", "-C", str(repo), "status", "--porcelain"], capture_output=True, text=True
        )
    except OSError:
        return "unknown"
    return (
        head.stdout.strip()[:12] + ("+dirty" if dirty.stdout.strip() else "")
        if head.returncode == 0
        else "unknown"
    )


def torch_run_context() -> str:
    """Code, CPU, torch version and thread count of this process, for a result's command line."""
    import torch

    return (
        f"code {code_version()}, {cpu_name()}, torch {torch.__version__}, {torch.get_num_threads()} thread(s)"
    )
