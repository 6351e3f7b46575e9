"""One run per work dir: an exclusive ``fcntl.flock`` on ``<workdir>/lock``.

The kernel drops the lock when the holder dies (even by kill -9), so a stale lock never blocks a rerun.
The lock file records the holder's pid and command (``run``, ``clean``) for the error message.
"""

from __future__ import annotations

import fcntl
import os
import time
from pathlib import Path

from go_core.errors import GoError


class LockedError(GoError):
    """Another go-pipeline run holds the work dir."""


class WorkdirLock:
    def __init__(self, workdir: Path, wait_s: float = 2.0, command: str = "run") -> None:
        self.path = Path(workdir) / "lock"
        self.command = command  # what the holder is doing, for the message a second process gets
        self.wait_s = wait_s  # short grace: the child of a just-killed run may still be exiting
        self._fd: int | None = None

    def acquire(self) -> WorkdirLock:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        deadline = time.monotonic() + self.wait_s
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() >= deadline:
                    pid, command = _parse_holder(os.pread(fd, 128, 0))
                    os.close(fd)
                    raise LockedError(
                        f"another `go-pipeline {command}` (pid {pid}) is using this work dir; wait for it "
                        f"to finish",
                        self.path,
                    ) from None
                time.sleep(0.05)
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()} {self.command}\n".encode("ascii"), 0)
        self._fd = fd
        return self

    def holder(self) -> str | None:
        """The pid recorded by the process holding the lock, or None when none holds it (never blocks)."""
        found = self.holder_info()
        return None if found is None else found[0]

    def holder_info(self) -> tuple[str, str] | None:
        """(pid, command) of the process holding the lock, or None when none holds it (never blocks)."""
        try:
            fd = os.open(self.path, os.O_RDONLY)
        except OSError:
            return None
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
            fcntl.flock(fd, fcntl.LOCK_UN)
            return None
        except BlockingIOError:
            return _parse_holder(os.pread(fd, 128, 0))
        finally:
            os.close(fd)

    @property
    def fd(self) -> int | None:
        return self._fd

    def release(self) -> None:
        if self._fd is not None:
            fcntl.flock(self._fd, fcntl.LOCK_UN)
            os.close(self._fd)
            self._fd = None

    def __enter__(self) -> WorkdirLock:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()


def _parse_holder(raw: bytes) -> tuple[str, str]:
    """(pid, command) from the lock file's ``PID COMMAND`` line (older files hold the pid only)."""
    parts = raw.decode("ascii", "replace").split()
    return (parts[0] if parts else "?"), (parts[1] if len(parts) > 1 else "run")
