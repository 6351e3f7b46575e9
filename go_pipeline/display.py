"""What a run shows: one line per step on stderr, rich progress bars for a step's iterations (on a
terminal), and every line (with timestamps) in the run's log file."""

from __future__ import annotations

import logging
import sys
import time
from dataclasses import dataclass, field
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


PROGRESS_LINE_EVERY_S = 10.0  # without a terminal: one progress line this often (stdout and the log)


@dataclass
class _Bar:
    """One progress bar's state: counts, when it started, the latest fields (loss, gaussians, ...)."""

    description: str
    total: int
    done: int
    fields: dict[str, Any] = field(default_factory=dict)
    started: float = field(default_factory=time.monotonic)
    last_line: float = field(default_factory=time.monotonic)

    def __post_init__(self) -> None:
        self.first = self.done

    def info(self) -> str:
        parts = []
        for k, v in self.fields.items():
            if k == "loss" and isinstance(v, (int, float)):
                parts.append(f"loss {v:.4g}")
            elif k == "gaussians" and isinstance(v, (int, float)):
                parts.append(f"{int(v):,} Gaussians")
            elif k == "psnr" and isinstance(v, (int, float)):
                parts.append(f"PSNR {v:.2f}")
            else:
                parts.append(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}")
        return ", ".join(parts)

    def line(self) -> str:
        elapsed = time.monotonic() - self.started
        pct = f" ({100 * self.done / self.total:.0f}%)" if self.total > 0 else ""
        text = f"{self.description} {self.done}/{self.total}{pct}, {_clock(elapsed)} elapsed"
        rate = (self.done - self.first) / elapsed if elapsed > 0 else 0.0
        if rate > 0 and self.total > self.done:
            text += f", ETA {_clock((self.total - self.done) / rate)}"
        info = self.info()
        return text + (f", {info}" if info else "")


def _clock(seconds: float) -> str:
    m, s = divmod(int(round(seconds)), 60)
    h, m = divmod(m, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


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
        self._totals: dict[int, _Bar] = {}
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
                TextColumn("ETA"),
                TimeRemainingColumn(),
                TextColumn("{task.fields[info]}"),
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
            bar = _Bar(desc, int(event["total"]), int(event["completed"]))
            self._totals[pid] = bar
            self._to_file(f"[{self.current_step}] {bar.line()}")
            if bars is not None:
                self._tasks[pid] = bars.add_task(desc, total=bar.total, completed=bar.done, info="")
        elif op == "advance":
            bar = self._totals.get(pid)
            if bar is None:
                return
            bar.done += int(event.get("n", 0))
            bar.fields.update(event.get("fields") or {})
            if bars is not None and pid in self._tasks:
                bars.update(self._tasks[pid], advance=int(event.get("n", 0)), info=bar.info())
            now = time.monotonic()
            if now - bar.last_line >= PROGRESS_LINE_EVERY_S:
                bar.last_line = now
                line = f"[{self.current_step}] {bar.line()}"
                self._to_file(line)
                if bars is None and not self.quiet:
                    print(f"  {line}", file=sys.stdout, flush=True)  # no terminal: a line every ~10 s
        elif op == "close":
            bar = self._totals.pop(pid, None)
            if bar is not None:
                self._to_file(f"[{self.current_step}] {bar.line()} (end)")
            if bars is not None and pid in self._tasks:
                bars.remove_task(self._tasks.pop(pid))

    def _to_file(self, text: str) -> None:
        """A line for the run log only (not the console)."""
        record = self.log.makeRecord(self.log.name, logging.INFO, __file__, 0, text, None, None)
        for handler in self.log.handlers:
            if not isinstance(handler, _ConsoleHandler):
                handler.handle(record)

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
