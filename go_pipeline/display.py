"""What a run shows: one line per step on stderr, rich progress bars for a step's iterations (on a
terminal), and every line (with timestamps) in the run's log file."""

from __future__ import annotations

import logging
import sys
from pathlib import Path
from typing import Any

LOG_FORMAT = "%(asctime)s %(levelname)-7s %(message)s"


class _ConsoleHandler(logging.Handler):
    def __init__(self, display: Display) -> None:
        super().__init__(level=logging.INFO)
        self.display = display

    def emit(self, record: logging.LogRecord) -> None:
        try:
            self.display.print(record.getMessage())
        except Exception:  # noqa: BLE001
            self.handleError(record)


class _HeldLines(logging.Handler):
    """Keeps log records in memory until the log file is opened (see Display.open_log)."""

    def __init__(self) -> None:
        super().__init__(level=logging.DEBUG)
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)


class Display:
    """Owns the run logger (file + console) and the progress bars of the step that is running."""

    def __init__(self, log_path: Path | None, quiet: bool = False, debug: bool = False) -> None:
        self.quiet = quiet
        self.debug = debug
        self.log = logging.getLogger(f"go_pipeline.run.{id(self)}")
        self.log.setLevel(logging.DEBUG)
        self.log.propagate = False
        self.log_path = log_path
        self._file_handler: logging.Handler | None = None
        self._held: _HeldLines | None = None
        if log_path is not None:  # lines are held until open_log(): a run with nothing to do writes no log
            self._held = _HeldLines()
            self.log.addHandler(self._held)
        self._console = None
        self._progress = None
        self._tasks: dict[int, Any] = {}
        self._totals: dict[int, tuple[int, int, str]] = {}
        if not quiet:
            self.log.addHandler(_ConsoleHandler(self))
        self.current_step = ""

    # log file -------------------------------------------------------------------------------------------
    def open_log(self) -> Path | None:
        """Create the run's log file (once) and write the lines held so far into it; its path."""
        if self._file_handler is None and self.log_path is not None:
            self.log_path.parent.mkdir(parents=True, exist_ok=True)
            self._file_handler = logging.FileHandler(self.log_path, encoding="utf-8")
            self._file_handler.setFormatter(logging.Formatter(LOG_FORMAT))
            if self._held is not None:
                self.log.removeHandler(self._held)
                for record in self._held.records:
                    self._file_handler.handle(record)
                self._held = None
            self.log.addHandler(self._file_handler)
        return self.log_path if self._file_handler is not None else None

    @property
    def log_file(self) -> Path | None:
        """The run log's path once it exists (None while nothing was written to a file)."""
        return self.log_path if self._file_handler is not None else None

    # console --------------------------------------------------------------------------------------
    @property
    def console(self):
        if self._console is None:
            from rich.console import Console

            self._console = Console(stderr=True, highlight=False)
        return self._console

    def print(self, text: str) -> None:
        if self.quiet:
            return
        if self._console is None and not sys.stderr.isatty():
            print(text, file=sys.stderr, flush=True)  # no rich import on the plain / no-op path
            return
        self.console.print(text, markup=False)

    # progress bars --------------------------------------------------------------------------------
    def _bars(self):
        if self._progress is None and not self.quiet and sys.stderr.isatty():
            from rich.progress import (
                BarColumn,
                MofNCompleteColumn,
                Progress,
                TextColumn,
                TimeElapsedColumn,
                TimeRemainingColumn,
            )

            self._progress = Progress(
                TextColumn("  {task.description}"),
                BarColumn(),
                MofNCompleteColumn(),
                TimeElapsedColumn(),
                TimeRemainingColumn(),
                console=self.console,
                transient=True,
            )
            self._progress.start()
        return self._progress

    def handle(self, event: dict[str, Any], records: dict[str, Any]) -> None:
        """An event from a step (child pipe or in-process context)."""
        kind = event.get("type")
        if kind == "log":
            self.log.log(int(event.get("level", logging.INFO)), f"[{self.current_step}] {event['message']}")
        elif kind == "record":
            records.update(event.get("values") or {})
        elif kind == "progress":
            self._progress_event(event)

    def _progress_event(self, event: dict[str, Any]) -> None:
        pid, op = int(event["id"]), event["op"]
        bars = self._bars()
        if op == "start":
            desc = f"{self.current_step}: {event.get('description') or ''}".rstrip(": ")
            self._totals[pid] = (int(event["completed"]), int(event["total"]), desc)
            self.log.debug(
                f"[{self.current_step}] progress start {desc} {event['completed']}/{event['total']}"
            )
            if bars is not None:
                self._tasks[pid] = bars.add_task(desc, total=event["total"], completed=event["completed"])
        elif op == "advance":
            done, total, desc = self._totals.get(pid, (0, 0, ""))
            self._totals[pid] = (done + int(event["n"]), total, desc)
            if bars is not None and pid in self._tasks:
                bars.advance(self._tasks[pid], int(event["n"]))
        elif op == "close":
            done, total, desc = self._totals.pop(pid, (0, 0, ""))
            self.log.debug(f"[{self.current_step}] progress end {desc} {done}/{total}")
            if bars is not None and pid in self._tasks:
                bars.remove_task(self._tasks.pop(pid))

    def end_step(self) -> None:
        """Drop any bars the step left open."""
        for pid in list(self._totals):
            self._progress_event({"id": pid, "op": "close"})

    def close(self) -> None:
        if self._progress is not None:
            self._progress.stop()
            self._progress = None
        if self._file_handler is not None:
            self._file_handler.close()
        for h in list(self.log.handlers):
            self.log.removeHandler(h)
