"""The contract between the runner and a step function.

A step module exposes ``run(ctx: StepContext, inputs: dict[str, Path], params: XParams) -> None``, where
``params`` is an instance of the step's params class (steps/registry.py, steps/params.py: typed fields, the
values resolved from pipeline.yaml, ``--profile`` and ``--set`` before anything runs); the step reads
``params.iterations``, never a default of its own. Its source and that of every go_core module it imports
are part of the cache key (go_pipeline.codehash); an optional ``VERSION = "..."`` forces a rerun without a
code change.

* ``inputs`` maps the input names declared in pipeline.yaml to the upstream artifact folders (read-only);
  the special value ``"@scene"`` in pipeline.yaml passes the raw scene folder (only the ``scene`` ingest
  step uses it; downstream steps read the ingested scene from the ``scene`` step's artifact with
  ``go_core.artifacts.read_scene``).
* The step writes every output file into ``ctx.out_dir`` (a temp folder the runner renames atomically
  into place when ``run`` returns; an exception leaves nothing behind that looks complete).
* Long steps save checkpoints into ``ctx.checkpoint_dir`` (persistent for this cache key across crashes;
  write them atomically) and resume from the newest one on start, so a killed run finishes with the same
  artifacts as an uninterrupted one. RNG state belongs in the checkpoint.
* ``ctx.record(**values)`` adds JSON-able values (counts, losses, "status"/"reason" for a skipped step,
  which model was used, ...) to the step manifest and so to the run report.
* Steps are deterministic on CPU for ``ctx.seed``; no globals; user-facing problems raise
  ``go_core.errors.GoError`` subclasses with one clear line.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, Protocol


class Progress(Protocol):
    def advance(self, n: int = 1, **fields: float | int | str) -> None:
        """``n`` more done; ``fields`` (e.g. ``loss=0.05, gaussians=26000``) are shown with the bar."""
        ...

    def close(self) -> None: ...


class StepContext(Protocol):
    step: str  # the step's name in pipeline.yaml
    out_dir: Path  # where outputs go (temp; renamed into place on success)
    checkpoint_dir: Path  # persistent per cache key, for mid-step resume
    seed: int
    device: str  # "cpu" or "cuda"
    log: logging.Logger

    def progress(self, total: int, description: str = "", completed: int = 0) -> Progress: ...

    def record(self, **values: Any) -> None: ...
