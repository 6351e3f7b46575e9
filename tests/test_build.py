"""The one-time C++ build survives kills: a stale torch build lock is cleared, one pinned ninja builds, a
rebuild is booked as build time (never as a step's), and the user is told before compiling starts."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from importlib import metadata
from pathlib import Path

import pytest

from go_core.render import build

REPO = Path(__file__).resolve().parents[1]


def test_stale_torch_build_lock_is_cleared(tmp_path, capsys):
    """A SIGKILL mid-build leaves torch's ``lock`` file (torch would wait on it forever); the next builder
    holds go-build.lock, so that file's owner is gone: it is removed, with a message naming the pid."""
    (tmp_path / "lock").write_text("")
    (tmp_path / "go-build.lock").write_text("424242\n")
    with build.build_lock(tmp_path):
        assert not (tmp_path / "lock").exists()
        assert (tmp_path / "go-build.lock").read_text().strip() == str(os.getpid())
    err = capsys.readouterr().err
    assert "removing a stale build lock" in err and "pid 424242" in err


def test_live_builder_keeps_its_lock(tmp_path):
    """While another process builds (holds go-build.lock), a second builder waits instead of removing
    torch's lock file under it."""
    (tmp_path / "lock").write_text("")
    code = (
        "import fcntl,os,sys,time; fd=os.open(sys.argv[1], os.O_RDWR|os.O_CREAT); "
        "fcntl.flock(fd, fcntl.LOCK_EX); print('held', flush=True); time.sleep(1.5); "
        "os.unlink(sys.argv[2])"  # the live builder finishes: torch removes its own lock file
    )
    holder = subprocess.Popen(
        [sys.executable, "-c", code, str(tmp_path / "go-build.lock"), str(tmp_path / "lock")],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "held"
        t0 = time.perf_counter()
        with build.build_lock(tmp_path):
            waited = time.perf_counter() - t0
            assert not (tmp_path / "lock").exists()
        assert waited > 0.5  # it waited for the live builder
    finally:
        holder.wait(timeout=30)


def test_one_pinned_ninja_builds():
    exe = build.find_ninja()
    assert exe.is_file()
    out = subprocess.run([str(exe), "--version"], capture_output=True, text=True, check=True).stdout
    assert out.strip().startswith(metadata.version("ninja"))
    path_before = os.environ["PATH"]
    with build._pinned_ninja():
        found = subprocess.run(["ninja", "--version"], capture_output=True, text=True).stdout
        assert found == out  # torch's `ninja` is this one during the build
    assert os.environ["PATH"] == path_before
    # one build tool: pyproject pins ninja exactly, and the installed one is that version
    pins = re.findall(r'"(ninja\b[^"]*)"', (REPO / "pyproject.toml").read_text())
    assert pins == [f"ninja=={metadata.version('ninja')}"], pins


def test_rebuild_counts_as_build_time_and_is_announced(monkeypatch, tmp_path, capsys):
    """A rebuild over an existing library (the case that put minutes of compiling into a step's time) is
    booked in BUILD_TIME, and a 'compiling once' line comes before it."""
    import time as _time

    from torch.utils import cpp_extension

    calls = []

    def fake_load(name, build_directory, **_):
        calls.append(capsys.readouterr().err)  # what was said before compiling
        _time.sleep(0.2)  # stands for compiling
        (Path(build_directory) / f"{name}.so").write_bytes(b"x" * len(calls))
        return "module"

    monkeypatch.setenv("TORCH_EXTENSIONS_DIR", str(tmp_path))
    monkeypatch.setattr(cpp_extension, "load", fake_load)
    before = build.BUILD_TIME.seconds
    try:
        build.load_extension.cache_clear()
        build.load_extension()
        build.load_extension.cache_clear()
        so = next(tmp_path.glob("*/*.so"))
        os.utime(so, ns=(1, 1))  # an old library: the fake rebuild rewrites it
        build.load_extension()
        assert build.BUILD_TIME.seconds - before >= 0.4  # both builds booked
        assert all("compiling the CPU rasterizer once" in said for said in calls)
    finally:
        build.load_extension.cache_clear()
        build.BUILD_TIME.seconds = before


@pytest.mark.slow
def test_kill_during_build_recovers(tmp_path):
    """SIGKILL a real build (process group) while torch's lock file exists; the next build finishes with a
    message about the stale lock instead of hanging."""
    env = dict(os.environ, TORCH_EXTENSIONS_DIR=str(tmp_path))
    cmd = [sys.executable, "-m", "go_core.render.build"]
    first = subprocess.Popen(cmd, env=env, cwd=REPO, start_new_session=True)
    deadline = time.monotonic() + 120
    while not list(tmp_path.glob("*/lock")) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert list(tmp_path.glob("*/lock")), "the build never took torch's lock"
    time.sleep(3)  # compiling
    os.killpg(first.pid, signal.SIGKILL)
    first.wait()
    assert list(tmp_path.glob("*/lock"))  # what a kill leaves behind
    second = subprocess.run(cmd, env=env, cwd=REPO, capture_output=True, text=True, timeout=900)
    assert second.returncode == 0, second.stderr
    assert "removing a stale build lock" in second.stderr
    assert "compiling the CPU rasterizer once" in second.stderr
