"""Headless Chromium (Debian's `chromium`) for the report's browser tests: a screenshot of a page, the
report's 3D viewer put on a scene camera (over the DevTools protocol on a pipe, no extra Python package),
and the facts of a screenshot. Also used by benchmarks/archive/report_screenshot.py."""

from __future__ import annotations

import json
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np

CHROMIUM_FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--hide-scrollbars",
]


def find_chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        found = shutil.which(name)
        if found:
            return found
    return None


def screenshot(html: Path, png: Path, width: int = 1200, height: int = 2400, timeout: float = 120) -> Path:
    """Render ``html`` in headless Chromium (a fresh profile) and save a ``width`` x ``height`` PNG."""
    browser = find_chromium()
    if browser is None:
        raise RuntimeError("chromium not found (Debian: apt-get install chromium)")
    png.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="go-chromium-") as profile:
        cmd = [
            browser,
            *CHROMIUM_FLAGS,
            f"--user-data-dir={profile}",
            f"--window-size={width},{height}",
            f"--screenshot={png.resolve()}",
            html.resolve().as_uri(),
        ]
        subprocess.run(cmd, check=True, capture_output=True, timeout=timeout)
    if not png.is_file():
        raise RuntimeError(f"chromium wrote no screenshot to {png}")
    return png


VIEWER_FLAGS = [  # WebGL without a GPU: SwiftShader through ANGLE
    "--headless=new",
    "--no-sandbox",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--hide-scrollbars",
    "--force-device-scale-factor=1",
]


class DevTools:
    """Headless Chromium driven over the DevTools protocol on a pipe (``--remote-debugging-pipe``: fd 3
    carries commands, fd 4 replies and events, each a JSON message ending in a NUL byte); no library."""

    def __init__(self, width: int = 1200, height: int = 1600, timeout: float = 120.0):
        import os

        browser = find_chromium()
        if browser is None:
            raise RuntimeError("chromium not found (Debian: apt-get install chromium)")
        self.timeout = timeout
        self._profile = tempfile.TemporaryDirectory(prefix="go-chromium-")
        to_child, self._send = os.pipe()
        self._recv, from_child = os.pipe()

        def wire() -> None:  # in the child: the pipe ends at fds 3 and 4 (via fds >= 10: no clash)
            import fcntl

            high = [fcntl.fcntl(fd, fcntl.F_DUPFD, 10) for fd in (to_child, from_child)]
            os.dup2(high[0], 3)
            os.dup2(high[1], 4)

        cmd = [
            browser,
            *VIEWER_FLAGS,
            f"--user-data-dir={self._profile.name}",
            f"--window-size={width},{height}",
        ]
        cmd += ["--remote-debugging-pipe", "about:blank"]
        # close_fds=False: fds 3 and 4, made by dup2 in the child, must survive; Python's own fds are
        # non-inheritable and close at exec anyway
        self.proc = subprocess.Popen(
            cmd, preexec_fn=wire, close_fds=False, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
        )
        os.close(to_child)
        os.close(from_child)
        self._buf, self._id, self.events = b"", 0, []
        target = self.call("Target.createTarget", url="about:blank")["targetId"]
        self.session = self.call("Target.attachToTarget", targetId=target, flatten=True)["sessionId"]

    def _read_message(self, deadline: float) -> dict:
        import os
        import select
        import time

        while b"\0" not in self._buf:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([self._recv], [], [], left)[0]:
                raise TimeoutError("chromium did not answer in time")
            chunk = os.read(self._recv, 1 << 20)
            if not chunk:
                raise RuntimeError("chromium closed the DevTools pipe")
            self._buf += chunk
        raw, self._buf = self._buf.split(b"\0", 1)
        return json.loads(raw)

    def call(self, method: str, session: bool = False, **params) -> dict:
        """Send one command (to the page's session when ``session``) and wait for its reply."""
        import os
        import time

        self._id += 1
        msg = {"id": self._id, "method": method, "params": params}
        if session:
            msg["sessionId"] = self.session
        os.write(self._send, json.dumps(msg).encode() + b"\0")
        deadline = time.monotonic() + self.timeout
        while True:
            reply = self._read_message(deadline)
            if reply.get("id") == self._id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply.get("result", {})
            self.events.append(reply)

    def evaluate(self, expression: str):
        """The value of a JavaScript expression in the page (awaiting a promise); errors raise."""
        out = self.call(
            "Runtime.evaluate", session=True, expression=expression, awaitPromise=True, returnByValue=True
        )
        if "exceptionDetails" in out:
            raise RuntimeError(
                f"{expression}: {out['exceptionDetails'].get('exception', out['exceptionDetails'])}"
            )
        return out["result"].get("value")

    def open(self, url: str) -> None:
        self.call("Page.enable", session=True)
        self.call("Page.navigate", session=True, url=url)
        self.evaluate(
            "new Promise(r => document.readyState === 'complete' ? r() : addEventListener('load', r))"
        )

    def screenshot(self, clip: dict) -> np.ndarray:
        """The page's pixels inside ``clip`` (x, y, width, height in CSS pixels), RGB uint8."""
        import base64
        import io

        from PIL import Image

        out = self.call(
            "Page.captureScreenshot",
            session=True,
            format="png",
            clip={**clip, "scale": 1},
            captureBeyondViewport=True,
        )
        return np.asarray(Image.open(io.BytesIO(base64.b64decode(out["data"]))).convert("RGB"))

    def close(self) -> None:
        try:
            self.call("Browser.close")
        except Exception:  # noqa: BLE001 - it may already be gone
            pass
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
        self._profile.cleanup()

    def __enter__(self) -> DevTools:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def viewer_shot(
    html: Path,
    kind: str = "test",
    index: int = 0,
    timeout: float = 180.0,
    view: str = "splats",
    clear: str | None = None,
) -> np.ndarray:
    """The report's 3D viewer put on scene camera ``index`` of ``kind`` (train / test), at the camera's own
    size, showing ``view`` ("splats" or "mesh"), on the background ``clear`` (a CSS colour; default the
    report's): what the browser shows, RGB uint8 [H, W, 3]."""
    with DevTools(timeout=timeout) as tab:
        tab.open(html.resolve().as_uri())
        tab.evaluate(
            "(async () => { while (!window.goViewer) await new Promise(r => setTimeout(r, 50)); "
            "await window.goViewer.ready; return true; })()"
        )
        if clear is not None:
            tab.evaluate(f"window.goViewer.renderer.setClearColor({json.dumps(clear)}, 1)")
        if view != "splats":
            tab.evaluate(f"window.goViewer.showTab({json.dumps(view)})")
        cam = tab.evaluate(f"window.goViewer.data.cameras[{json.dumps(kind)}][{int(index)}]")
        clip = tab.evaluate(
            f"window.goViewer.showView({json.dumps(kind)}, {int(index)}, {cam['width']}, {cam['height']})"
        )
        return tab.screenshot(clip)


def check_screenshot(png: Path) -> dict:
    """Facts of a screenshot: size, share of non-white pixels and of colourful pixels (images shown)."""
    from PIL import Image

    rgb = np.asarray(Image.open(png).convert("RGB")).astype(np.int16)
    non_white = (rgb.min(axis=-1) < 240).mean()
    colourful = ((rgb.max(axis=-1) - rgb.min(axis=-1)) > 40).mean()
    return {
        "png": str(png),
        "width": int(rgb.shape[1]),
        "height": int(rgb.shape[0]),
        "non_white_fraction": round(float(non_white), 4),
        "colourful_fraction": round(float(colourful), 4),
    }
