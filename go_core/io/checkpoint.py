"""Reading mid-step checkpoints without running code from them.

Checkpoints live in the work dir, which may come with a scene folder someone else prepared: a pickle there
could run anything on ``torch.load``. They are therefore read with torch's ``weights_only`` unpickler, which
admits tensors, plain containers (dict, list, tuple), numbers, strings and None, and refuses every other
global. A refused or unreadable file is skipped with a warning (the step recomputes), never executed.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)


class UnsafeCheckpoint(ValueError):
    """The file is not a plain checkpoint (it references code, or is not a torch file at all)."""


def load_checkpoint(path: str | Path) -> Any:
    """The checkpoint at ``path`` (tensors on the CPU, plain containers); ``UnsafeCheckpoint`` for a file
    holding anything else. Never unpickles code."""
    import torch

    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # noqa: BLE001 - UnpicklingError, RuntimeError (not a zip), EOFError ...
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise UnsafeCheckpoint(f"{path}: not a plain checkpoint ({first[:160]})") from None


def try_load_checkpoint(path: str | Path) -> Any | None:
    """``load_checkpoint`` or None (with a warning) for a foreign, damaged or code-carrying file."""
    try:
        return load_checkpoint(path)
    except UnsafeCheckpoint as e:
        log.warning(f"ignoring checkpoint {e}")
        return None
