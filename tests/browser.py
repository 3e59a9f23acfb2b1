"""Headless Chromium driven over the DevTools protocol on a pipe, for the tests that look at a page.

Chromium's ``--dump-dom`` and ``--screenshot`` take the page when a virtual-time budget runs out, and
events that arrive from outside the page's own timers (a video's first frame, a missing file's error)
come in real time: on a loaded machine they arrive after the budget and the test sees half a page.
Here a test waits for the condition it needs, in real time, with a deadline, and fails with the last
state it saw when the deadline passes.
"""
from __future__ import annotations

import base64
import json
import os
import shutil
import subprocess
import time

import pytest

CHROMIUM = ("chromium-headless-shell", "chromium")  # Debian packages; scripts/setup.sh installs the first
DEADLINE_S = 90.0  # real seconds a condition may take; the loaded 2-core machine needs a few


def chromium() -> str:
    for name in CHROMIUM:
        path = shutil.which(name)
        if path:
            return path
    pytest.fail("headless Chromium is not installed (Debian package chromium-headless-shell): run "
                "`bash scripts/setup.sh`; the page was NOT checked in a browser")


class Browser:
    """One headless Chromium with one page, ``width`` x ``height`` CSS pixels at scale 1."""

    def __init__(self, width: int = 1400, height: int = 1400):
        to_chrome_r, self._to_chrome = os.pipe()
        self._from_chrome, from_chrome_w = os.pipe()
        # Chromium reads commands on fd 3 and writes answers on fd 4 (--remote-debugging-pipe).
        self._proc = subprocess.Popen(
            ["bash", "-c", f'exec "$0" "$@" 3<&{to_chrome_r} 4>&{from_chrome_w}', chromium(),
             "--headless", "--no-sandbox", "--disable-gpu", "--allow-file-access-from-files",
             "--autoplay-policy=no-user-gesture-required", "--force-device-scale-factor=1",
             f"--window-size={width},{height}", "--remote-debugging-pipe", "about:blank"],
            pass_fds=(to_chrome_r, from_chrome_w), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        os.close(to_chrome_r)
        os.close(from_chrome_w)
        self._buffer, self._next_id = b"", 0
        target = self._call("Target.createTarget", url="about:blank")["targetId"]
        self._session = self._call("Target.attachToTarget", targetId=target, flatten=True)["sessionId"]
        self._call("Emulation.setDeviceMetricsOverride", session=True, width=width, height=height,
                   deviceScaleFactor=1, mobile=False)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self) -> None:
        try:
            self._call("Browser.close")
        except (OSError, RuntimeError):
            pass
        try:
            self._proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()
        os.close(self._to_chrome)
        os.close(self._from_chrome)

    def _call(self, method: str, session: bool = False, **params) -> dict:
        self._next_id += 1
        message = {"id": self._next_id, "method": method, "params": params}
        if session:
            message["sessionId"] = self._session
        os.write(self._to_chrome, json.dumps(message).encode() + b"\0")
        while True:
            while b"\0" not in self._buffer:
                chunk = os.read(self._from_chrome, 1 << 16)
                if not chunk:
                    raise RuntimeError(f"Chromium closed its pipe: {self._proc.stderr.read()[-2000:]!r}")
                self._buffer += chunk
            raw, self._buffer = self._buffer.split(b"\0", 1)
            answer = json.loads(raw)
            if answer.get("id") == self._next_id:  # events carry no id
                if "error" in answer:
                    raise RuntimeError(f"{method}: {answer['error']}")
                return answer.get("result", {})

    def open(self, url: str) -> None:
        self._call("Page.navigate", session=True, url=url)
        self.wait_for("document.readyState === 'complete'")

    def evaluate(self, expression: str):
        """The JSON value of a JavaScript expression in the page."""
        result = self._call("Runtime.evaluate", session=True, expression=expression, returnByValue=True,
                            awaitPromise=True)
        if "exceptionDetails" in result:
            raise RuntimeError(f"{expression}: {result['exceptionDetails']}")
        return result["result"].get("value")

    def wait_for(self, condition: str, state: str = "null", deadline_s: float = DEADLINE_S):
        """Polls ``condition`` until it is true; returns ``state`` evaluated then. Fails the test with
        the last state when ``deadline_s`` real seconds pass first."""
        end = time.monotonic() + deadline_s
        while True:
            if self.evaluate(f"!!({condition})"):
                return self.evaluate(state)
            if time.monotonic() > end:
                pytest.fail(f"the page did not reach `{condition}` in {deadline_s:g} s: {self.evaluate(state)}")
            time.sleep(0.1)

    def screenshot(self) -> bytes:
        """The viewport as PNG bytes, after the next two frames are painted."""
        self.evaluate("new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)))")
        return base64.b64decode(self._call("Page.captureScreenshot", session=True, format="png")["data"])
