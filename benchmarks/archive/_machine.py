"""benchmarks/_lib/machine.py for the archived scripts, which run as ``python benchmarks/archive/X.py`` (this
folder first on ``sys.path``): the same functions, read from the maintained file."""

from __future__ import annotations

import runpy
from pathlib import Path

_shared = runpy.run_path(str(Path(__file__).resolve().parents[1] / "_lib" / "machine.py"))
cpu_name = _shared["cpu_name"]
code_version = _shared["code_version"]
torch_run_context = _shared["torch_run_context"]
