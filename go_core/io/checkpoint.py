"""Mid-step checkpoints: the one toolkit every training loop resumes with (``Checkpoints``, ``LossLog``,
``fingerprint_of``), and reading them without running code from them.

Checkpoints live in the work dir, which may come with a scene folder someone else prepared: a pickle there
could run anything on ``torch.load``. They are therefore read with torch's ``weights_only`` unpickler, which
admits tensors, plain containers (dict, list, tuple), numbers, strings and None, and refuses every other
global. A refused or unreadable file is skipped with a warning (the step recomputes), never executed.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
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


def fingerprint_of(value: Any) -> str:
    """A short hash of JSON-able ``value`` (a loop's settings and inputs): a checkpoint is resumed from only
    by a loop with the same fingerprint."""
    import hashlib
    import json

    return hashlib.sha256(json.dumps(value, sort_keys=True).encode()).hexdigest()[:16]


@dataclass(frozen=True)
class CheckpointSpec:
    """Where and how often a loop saves: every ``every`` iterations (0: never) into ``directory``, keeping
    the newest ``keep``."""

    directory: Path
    every: int = 500
    keep: int = 1


@dataclass(frozen=True)
class Checkpoints:
    """The numbered checkpoints of one loop: ``<prefix>_<step:07d>.pt`` (``save`` / ``newest``: tensors and
    plain containers, read back without unpickling code) or ``.safetensors`` (``save_tensors`` /
    ``newest_tensors``: tensors plus JSON metadata, no pickle at all). Each is written atomically, the newest
    ``spec.keep`` are kept, and one is resumed from only when its ``format`` and fingerprint match. The one
    implementation of the resume that every training loop (coarse, repair, the two tuning loops) relies on
    for bit-identical results after a kill."""

    spec: CheckpointSpec
    prefix: str
    format: int | str

    def due(self, step: int, last: int) -> bool:
        """Whether to save after ``step`` of a loop that ends at ``last`` (never after the last one)."""
        return self.spec.every > 0 and step % self.spec.every == 0 and step < last

    def _paths(self, suffix: str) -> list[Path]:
        folder = Path(self.spec.directory)
        return sorted(folder.glob(f"{self.prefix}_*{suffix}")) if folder.is_dir() else []

    def _prune(self, suffix: str) -> None:
        for old in self._paths(suffix)[: -max(self.spec.keep, 1)]:
            old.unlink(missing_ok=True)

    def save(self, step: int, fingerprint: str, payload: dict[str, Any]) -> None:
        from go_core.io.atomic import atomic_torch_save

        folder = Path(self.spec.directory)
        folder.mkdir(parents=True, exist_ok=True)
        body = {"format": self.format, "fingerprint": fingerprint, "step": step, **payload}
        atomic_torch_save(folder / f"{self.prefix}_{step:07d}.pt", body)
        self._prune(".pt")

    def newest(self, fingerprint: str) -> dict[str, Any] | None:
        """The newest matching ``save`` payload (with ``step``), or None."""
        for path in reversed(self._paths(".pt")):
            payload = try_load_checkpoint(path)  # tensors and plain containers only: never code
            if not isinstance(payload, dict):
                continue
            if payload.get("format") == self.format and payload.get("fingerprint") == fingerprint:
                return payload
        return None

    def save_tensors(self, step: int, fingerprint: str, tensors: dict, meta: dict[str, Any]) -> None:
        from go_core.io.safetensors_file import write_safetensors

        folder = Path(self.spec.directory)
        folder.mkdir(parents=True, exist_ok=True)
        state = {"format": self.format, "fingerprint": fingerprint, "step": step, **meta}
        tensors = {k: v.detach().contiguous().clone() for k, v in tensors.items()}
        path = folder / f"{self.prefix}_{step:07d}.safetensors"
        write_safetensors(path, tensors, {"state": json.dumps(state, sort_keys=True)})
        self._prune(".safetensors")

    def newest_tensors(self, fingerprint: str) -> tuple[dict, dict[str, Any]] | None:
        """The newest matching ``save_tensors`` (tensors, metadata with ``step``), or None."""
        from safetensors import SafetensorError
        from safetensors.torch import safe_open

        for path in reversed(self._paths(".safetensors")):
            try:
                with safe_open(str(path), framework="pt") as f:
                    meta = json.loads((f.metadata() or {}).get("state", "{}"))
                    if meta.get("format") != self.format or meta.get("fingerprint") != fingerprint:
                        continue
                    return {k: f.get_tensor(k) for k in f.keys()}, meta  # noqa: SIM118
            except (SafetensorError, OSError, ValueError):
                continue  # a torn file cannot exist (atomic writes); anything unreadable is simply not used
        return None


@dataclass
class LossLog:
    """A training loop's loss log: every ``every`` steps (and at ``last``) one entry with the mean loss
    since the previous entry and the given fields. Its ``entries`` and ``running`` sum go into checkpoints."""

    every: int
    last: int
    entries: list[dict] = field(default_factory=list)
    running: float = 0.0

    def add(self, step: int, loss: float, **fields: Any) -> None:
        every = max(self.every, 1)
        self.running += loss
        if step % every == 0 or step == self.last:
            n = step % every or every
            self.entries.append({"step": step, "loss": round(self.running / n, 6), **fields})
            self.running = 0.0
