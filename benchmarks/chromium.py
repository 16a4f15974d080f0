"""Drive a headless Chromium from Python's standard library: the DevTools protocol over a pipe.

Used by the browser test of ``mdvae view``'s page (tests/test_view_browser.py) and by
benchmarks/view_page.py. Chromium is started with ``--remote-debugging-pipe``: it reads JSON
commands from its file descriptor 3 and writes answers and events to descriptor 4, each
message ended by a NUL byte.

    with Chromium.launch() as browser:
        page = browser.open_page(width=1200, height=900)
        page.navigate("file:///tmp/walk.html")
        page.wait_for("window.mdvaeView && window.mdvaeView.ready")
        png = page.screenshot()
"""

from __future__ import annotations

import base64
import contextlib
import json
import os
import select
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

#: flags for a quiet, sandbox-free, offline headless run (a test machine's root user included)
FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--no-default-browser-check",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-extensions",
    "--disable-dev-shm-usage",
    "--mute-audio",
    "--hide-scrollbars",
)


def find_chromium() -> str | None:
    """The Chromium executable: $MDVAE_CHROMIUM, else chromium / chromium-browser on PATH."""
    named = os.environ.get("MDVAE_CHROMIUM")
    if named:
        return named if shutil.which(named) else None
    for name in ("chromium", "chromium-browser"):
        found = shutil.which(name)
        if found:
            return found
    return None


class ProtocolError(RuntimeError):
    """Chromium answered a command with an error, or did not answer in time."""


class Chromium:
    """One headless Chromium process and its DevTools pipe."""

    def __init__(self, process: subprocess.Popen, to_browser: int, from_browser: int, profile):
        self.process = process
        self._out, self._in = to_browser, from_browser
        self._profile = profile
        self._buffer = b""
        self._next_id = 0
        self.events: list[dict] = []

    @classmethod
    def launch(cls, executable: str | None = None, extra_flags: tuple[str, ...] = ()) -> Chromium:
        """Start Chromium with a fresh profile folder (deleted on close)."""
        executable = executable or find_chromium()
        if executable is None:
            raise FileNotFoundError("no chromium on PATH (apt-get install chromium)")
        profile = tempfile.TemporaryDirectory(prefix="mdvae-chromium-")
        cmd_read, cmd_write = os.pipe()
        out_read, out_write = os.pipe()

        def child_fds() -> None:  # runs in the child: the pipe ends become its fds 3 and 4
            a, b = os.dup(cmd_read), os.dup(out_write)
            os.dup2(a, 3)
            os.dup2(b, 4)

        args = [executable, *FLAGS, *extra_flags, f"--user-data-dir={profile.name}",
                "--remote-debugging-pipe", "about:blank"]  # fmt: skip
        process = subprocess.Popen(
            args,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            preexec_fn=child_fds,
            close_fds=False,
        )
        os.close(cmd_read)
        os.close(out_write)
        return cls(process, cmd_write, out_read, profile)

    # --- the pipe ---------------------------------------------------------------------------

    def _read_message(self, deadline: float) -> dict:
        while b"\0" not in self._buffer:
            left = deadline - time.monotonic()
            if left <= 0:
                raise ProtocolError("chromium did not answer in time")
            ready, _, _ = select.select([self._in], [], [], left)
            if ready:
                chunk = os.read(self._in, 1 << 20)
                if not chunk:
                    raise ProtocolError("chromium closed its DevTools pipe (it exited)")
                self._buffer += chunk
        message, self._buffer = self._buffer.split(b"\0", 1)
        return json.loads(message)

    def send(self, method: str, params: dict | None = None, session: str | None = None,
             timeout: float = 30.0) -> dict:  # fmt: skip
        """Send one command and wait for its answer (events meanwhile go to ``events``)."""
        self._next_id += 1
        message = {"id": self._next_id, "method": method, "params": params or {}}
        if session:
            message["sessionId"] = session
        os.write(self._out, json.dumps(message).encode() + b"\0")
        deadline = time.monotonic() + timeout
        while True:
            reply = self._read_message(deadline)
            if reply.get("id") == self._next_id:
                if "error" in reply:
                    raise ProtocolError(f"{method}: {reply['error'].get('message')}")
                return reply.get("result", {})
            self.events.append(reply)

    def poll_events(self, seconds: float = 0.0) -> None:
        """Collect events that arrive within ``seconds``."""
        deadline = time.monotonic() + seconds
        while True:
            left = deadline - time.monotonic()
            ready, _, _ = select.select([self._in], [], [], max(left, 0))
            if not ready:
                if b"\0" not in self._buffer:
                    return
            else:
                chunk = os.read(self._in, 1 << 20)
                if not chunk:
                    return
                self._buffer += chunk
            while b"\0" in self._buffer:
                message, self._buffer = self._buffer.split(b"\0", 1)
                self.events.append(json.loads(message))
            if left <= 0:
                return

    # --- pages ------------------------------------------------------------------------------

    def open_page(self, width: int = 1280, height: int = 900) -> Page:
        """A new tab of the given viewport, attached, with console and log events on."""
        target = self.send("Target.createTarget", {"url": "about:blank"})["targetId"]
        session = self.send("Target.attachToTarget", {"targetId": target, "flatten": True})[
            "sessionId"
        ]
        page = Page(self, session)
        for domain in ("Page", "Runtime", "Log", "Network"):
            page.call(f"{domain}.enable")
        metrics = {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": False}
        page.call("Emulation.setDeviceMetricsOverride", metrics)
        return page

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.send("Browser.close", timeout=5)
        try:
            self.process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
        for fd in (self._out, self._in):
            with contextlib.suppress(OSError):
                os.close(fd)
        self._profile.cleanup()

    def __enter__(self) -> Chromium:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class Page:
    """One attached tab."""

    def __init__(self, browser: Chromium, session: str):
        self.browser, self.session = browser, session

    def call(self, method: str, params: dict | None = None, timeout: float = 30.0) -> dict:
        return self.browser.send(method, params, session=self.session, timeout=timeout)

    def navigate(self, url: str) -> None:
        self.call("Page.navigate", {"url": url})

    def evaluate(self, expression: str, timeout: float = 30.0):
        """The value of a JavaScript expression (promises awaited); ProtocolError if it threw."""
        result = self.call(
            "Runtime.evaluate",
            {"expression": expression, "returnByValue": True, "awaitPromise": True},
            timeout=timeout,
        )
        if "exceptionDetails" in result:
            details = result["exceptionDetails"]
            text = details.get("exception", {}).get("description") or details.get("text")
            raise ProtocolError(f"{expression!r} threw: {text}")
        return result["result"].get("value")

    def wait_for(self, expression: str, timeout: float = 30.0, interval: float = 0.02) -> float:
        """Poll until ``expression`` is truthy; -> seconds waited."""
        start = time.monotonic()
        while not self.evaluate(expression):
            if time.monotonic() - start > timeout:
                raise ProtocolError(f"timed out waiting for {expression!r}")
            time.sleep(interval)
        return time.monotonic() - start

    def screenshot(self) -> bytes:
        """The viewport as PNG bytes."""
        return base64.b64decode(self.call("Page.captureScreenshot", {"format": "png"})["data"])

    def errors(self) -> list[str]:
        """Console errors, uncaught exceptions and error log entries seen so far on this page."""
        self.browser.poll_events(0.05)
        found = []
        for event in self.browser.events:
            if event.get("sessionId") != self.session:
                continue
            method, params = event.get("method"), event.get("params", {})
            if method == "Runtime.exceptionThrown":
                details = params.get("exceptionDetails", {})
                found.append(details.get("exception", {}).get("description") or details.get("text"))
            elif method == "Runtime.consoleAPICalled" and params.get("type") in ("error", "assert"):
                found.append(
                    " ".join(str(a.get("value", a.get("description"))) for a in params["args"])
                )
            elif method == "Log.entryAdded" and params.get("entry", {}).get("level") == "error":
                found.append(params["entry"].get("text"))
        return found

    def requests(self) -> list[str]:
        """URLs this page requested (Network.requestWillBeSent) so far."""
        self.browser.poll_events(0.05)
        return [
            e["params"]["request"]["url"]
            for e in self.browser.events
            if e.get("sessionId") == self.session and e.get("method") == "Network.requestWillBeSent"
        ]


def file_url(path: Path | str) -> str:
    return Path(path).resolve().as_uri()
