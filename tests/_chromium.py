"""Headless Chromium for the browser tests, driven through the DevTools protocol over a pipe.

Used by ``tests/test_viz.py`` and ``tests/test_browser.py``. The tests that need it are marked
``@pytest.mark.browser`` and skip, with the reason, when no ``chromium`` is on PATH (``make browser``
installs Debian's; ``make test`` never installs system packages).
"""

from __future__ import annotations

import base64
import contextlib
import json
import os
import select
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

needs_chromium = pytest.mark.skipif(
    shutil.which("chromium") is None,
    reason="chromium is not on PATH: `make browser` installs it (apt-get install chromium)",
)
_TRAMPOLINE = """
import fcntl, os, sys
r, w = (fcntl.fcntl(int(fd), fcntl.F_DUPFD, 10) for fd in sys.argv[1:3])
for fd in sys.argv[1:3]:
    os.close(int(fd))
os.dup2(r, 3)
os.dup2(w, 4)
os.close(r)
os.close(w)
os.execv(sys.argv[3], sys.argv[3:])
"""


class Chromium:
    """Headless Chromium driven through the DevTools protocol over a pipe (its fds 3 and 4).

    The pipe needs no port and no websocket client. ``close`` asks the browser to quit (so that it
    reaps its own helper processes), waits for it, and kills its process group by PID if it hangs.
    """

    FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
             "--disable-background-networking", "--disable-component-update", "--disable-sync"]

    def __init__(self, profile: Path, extra_flags: tuple[str, ...] = ()):
        to_child_r, self._to_child = os.pipe()
        self._from_child, from_child_w = os.pipe()
        # Chromium reads the DevTools pipe on fd 3 and writes on fd 4: a small trampoline moves our
        # ends there and execs the browser (same PID; no preexec_fn in this threaded process)
        args = [sys.executable, "-c", _TRAMPOLINE, str(to_child_r), str(from_child_w), shutil.which("chromium"),
                *self.FLAGS, *extra_flags, f"--user-data-dir={profile}", "--remote-debugging-pipe", "about:blank"]
        self.proc = subprocess.Popen(args, pass_fds=(to_child_r, from_child_w), start_new_session=True,
                                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        os.close(to_child_r)
        os.close(from_child_w)
        self._buffer = b""
        self._next_id = 0

    def call(self, method: str, params: dict | None = None, session: str | None = None, timeout: float = 20.0):
        self._next_id += 1
        message = {"id": self._next_id, "method": method, "params": params or {}}
        if session:
            message["sessionId"] = session
        os.write(self._to_child, json.dumps(message).encode() + b"\0")
        deadline = time.monotonic() + timeout
        while True:
            while b"\0" not in self._buffer:
                left = deadline - time.monotonic()
                if left <= 0 or not select.select([self._from_child], [], [], left)[0]:
                    raise TimeoutError(f"no answer to {method} in {timeout} s")
                chunk = os.read(self._from_child, 1 << 20)
                if not chunk:
                    raise EOFError(f"chromium closed the DevTools pipe during {method}")
                self._buffer += chunk
            raw, self._buffer = self._buffer.split(b"\0", 1)
            reply = json.loads(raw)
            if reply.get("id") == self._next_id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply["result"]

    def close(self) -> None:
        try:
            if self.proc.poll() is None:
                self.call("Browser.close", timeout=5)
            self.proc.wait(timeout=10)
        except (OSError, TimeoutError, EOFError, RuntimeError, subprocess.TimeoutExpired):
            if self.proc.poll() is None:
                os.killpg(self.proc.pid, signal.SIGKILL)  # the group of the browser we started
            self.proc.wait()
        finally:
            for fd in (self._to_child, self._from_child):
                try:
                    os.close(fd)
                except OSError:
                    pass


#: [s] how long the first call may wait for a starting browser (not a speed bar: a hang turned into a failure)
STARTUP = 90.0


class Page:
    """One page of a :class:`Chromium`: navigate, evaluate JavaScript, take screenshots."""

    def __init__(self, browser: Chromium, width: int, height: int):
        self.browser = browser
        # the first call waits for the browser to start: under load (a full CI run on 2 cores) that took over 20 s
        targets = browser.call("Target.getTargets", timeout=STARTUP)["targetInfos"]
        target = next(t for t in targets if t["type"] == "page")
        self.session = browser.call("Target.attachToTarget", {"targetId": target["targetId"], "flatten": True})[
            "sessionId"]
        browser.call("Emulation.setDeviceMetricsOverride",
                     {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": False}, self.session)

    def navigate(self, url: str) -> None:
        self.browser.call("Page.navigate", {"url": url}, self.session)

    def evaluate(self, expression: str):
        params = {"expression": expression, "returnByValue": True, "awaitPromise": True}  # a Promise: its value
        reply = self.browser.call("Runtime.evaluate", params, self.session)
        if "exceptionDetails" in reply:
            raise RuntimeError(f"{expression!r} raised: {reply['exceptionDetails']}")
        return reply["result"].get("value")

    def wait_for(self, expression: str, timeout: float = 30.0, what: str = "the condition") -> None:
        deadline = time.monotonic() + timeout
        while not self.evaluate(expression):
            assert time.monotonic() < deadline, f"the page never reached {what} in {timeout} s"
            time.sleep(0.1)

    def screenshot(self) -> np.ndarray:
        from io import BytesIO

        from PIL import Image

        data = self.browser.call("Page.captureScreenshot", {"format": "png"}, self.session)["data"]
        return np.asarray(Image.open(BytesIO(base64.b64decode(data))).convert("RGB"))


@contextlib.contextmanager
def open_page(url: str, profile: Path, width: int = 800, height: int = 600, extra_flags: tuple[str, ...] = ()):
    """A headless Chromium showing ``url`` at ``width`` x ``height`` pixels; the browser is closed after.
    ``extra_flags`` go to Chromium (e.g. :data:`NO_WEBGL`)."""
    browser = Chromium(profile, extra_flags)
    try:
        page = Page(browser, width, height)
        page.navigate(url)
        yield page
    finally:
        browser.close()


MESHCAT_READY = "typeof viewer !== 'undefined' && viewer.animator.duration > 0"

#: Chromium without WebGL (as a browser with it turned off or its graphics driver blocked)
NO_WEBGL = ("--disable-webgl", "--disable-webgl2", "--disable-3d-apis")


def scrub(page: Page, t: float) -> None:
    """Pause meshcat's animation and move it to ``t`` seconds of playback (as the page's time scrubber
    does), then wait until it has been drawn: a fixed time instead of a running clock, so that what a test
    sees does not depend on how fast the machine is."""
    page.evaluate(f"(() => {{ const a = viewer.animator; a.pause(); a.seek({t!r}); a.display_progress({t!r}); "
                  "viewer.set_dirty(); return true; })()")
    page.wait_for(f"Math.abs(viewer.animator.time - {t!r}) < 1e-9", what=f"the animation at {t} s")
    page.evaluate("new Promise(r => requestAnimationFrame(() => requestAnimationFrame(() => r(true))))")
