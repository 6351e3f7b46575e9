"""The runner's implementation of ``go_pipeline.steps._api.StepContext``.

A context forwards progress and ``record`` values to an ``EventSink``: in a child process that is a pipe
to the parent (``PipeSink``); in-process it is the parent's display directly.
"""

from __future__ import annotations

import json
import logging
import os
import threading
import time
from pathlib import Path
from typing import Any, Protocol


class EventSink(Protocol):
    def send(self, event: dict[str, Any]) -> None: ...


class PipeSink:
    """JSON lines to a file descriptor (the parent reads them); thread-safe."""

    def __init__(self, fd: int) -> None:
        self._file = os.fdopen(fd, "w", buffering=1, encoding="utf-8")
        self._lock = threading.Lock()

    def send(self, event: dict[str, Any]) -> None:
        line = json.dumps(event, default=str) + "\n"
        with self._lock:
            self._file.write(line)
            self._file.flush()

    def close(self) -> None:
        with self._lock:
            self._file.close()


class SinkLogHandler(logging.Handler):
    """Log records of a step travel as events, so the parent writes them to the run log and console."""

    def __init__(self, sink: EventSink) -> None:
        super().__init__()
        self.sink = sink

    def emit(self, record: logging.LogRecord) -> None:
        try:
            self.sink.send({"type": "log", "level": record.levelno, "message": record.getMessage()})
        except Exception:  # noqa: BLE001 - logging must never crash a step
            self.handleError(record)


class StepProgress:
    """A progress bar handle; advances are batched to at most ~10 events per second."""

    def __init__(self, sink: EventSink, total: int, description: str, completed: int, bar_id: int) -> None:
        self.id = bar_id
        self.sink = sink
        self._pending = 0
        self._fields: dict[str, Any] = {}
        self._last = 0.0
        self._closed = False
        sink.send(
            {
                "type": "progress",
                "op": "start",
                "id": self.id,
                "total": int(total),
                "description": description,
                "completed": int(completed),
            }
        )

    def advance(self, n: int = 1, **fields: Any) -> None:
        """``n`` more done; ``fields`` (latest values, e.g. loss, gaussians) travel with the next event."""
        self._pending += n
        if fields:
            self._fields.update(fields)
        now = time.monotonic()
        if now - self._last >= 0.1:
            self._flush(now)

    def _flush(self, now: float) -> None:
        if self._pending or self._fields:
            event = {"type": "progress", "op": "advance", "id": self.id, "n": self._pending}
            if self._fields:
                event["fields"] = self._fields
                self._fields = {}
            self.sink.send(event)
            self._pending = 0
        self._last = now

    def close(self) -> None:
        if not self._closed:
            self._flush(time.monotonic())
            self.sink.send({"type": "progress", "op": "close", "id": self.id})
            self._closed = True

    def __enter__(self) -> StepProgress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class RunnerStepContext:
    """What a step function receives as ``ctx`` (see steps/_api.py for the contract)."""

    def __init__(
        self,
        step: str,
        out_dir: Path,
        checkpoint_dir: Path,
        seed: int,
        device: str,
        sink: EventSink,
        log: logging.Logger,
    ) -> None:
        self.step = step
        self.out_dir = Path(out_dir)
        self.checkpoint_dir = Path(checkpoint_dir)
        self.seed = int(seed)
        self._device_request = device
        self._device: str | None = None if device == "auto" else device
        self.sink = sink
        self.log = log
        self.records: dict[str, Any] = {}
        self._bars = 0

    @property
    def device(self) -> str:
        """ "cuda" when requested, or when "auto" and CUDA is available; else "cpu". Resolved lazily so
        steps that never ask do not import torch."""
        if self._device is None:
            import torch

            self._device = "cuda" if torch.cuda.is_available() else "cpu"
        return self._device

    def resolved_device(self) -> str:
        """The device for the manifest without importing torch when the step did not."""
        if self._device is not None:
            return self._device
        import sys

        if "torch" in sys.modules:
            return self.device
        return "cpu"

    def progress(self, total: int, description: str = "", completed: int = 0) -> StepProgress:
        self._bars += 1
        return StepProgress(self.sink, total, description or self.step, completed, self._bars)

    def record(self, **values: Any) -> None:
        json.dumps(values, allow_nan=False, default=None)  # raise here, not later, if not JSON-able
        self.records.update(values)
        self.sink.send({"type": "record", "values": values})
