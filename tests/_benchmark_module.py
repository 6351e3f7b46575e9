"""Import a script of benchmarks/ as a module (benchmarks/ is not a package), for tests of its helpers, and
the repair prior's corpus package (benchmarks/prior/corpus/, not installed)."""

from __future__ import annotations

import importlib
import importlib.util
import sys
from pathlib import Path
from types import ModuleType

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"
PRIOR = BENCHMARKS / "prior"


def _on_path(folder: Path) -> None:
    if str(folder) not in sys.path:
        sys.path.append(str(folder))


def benchmark_module(name: str) -> ModuleType:
    """``benchmarks/<name>.py`` (``name`` may name a folder: ``prior/repair_corpus``), executed as a fresh
    module, with benchmarks/ and the script's folder on ``sys.path`` as when the script runs (its shared
    helpers, e.g. ``_lib.machine``, and its neighbours import)."""
    path = BENCHMARKS / f"{name}.py"
    _on_path(BENCHMARKS)
    _on_path(path.parent)
    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[path.stem] = module  # a dataclass of the script looks its module up by name
    spec.loader.exec_module(module)
    return module


def corpus_module(name: str) -> ModuleType:
    """``benchmarks/prior/corpus/<name>.py``, imported as ``corpus.<name>`` as the prior's scripts do."""
    _on_path(PRIOR)
    return importlib.import_module(f"corpus.{name}")
