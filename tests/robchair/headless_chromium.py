"""Open a local page in headless Chromium and collect what its console and the page reported, over the
Chrome DevTools Protocol on a pipe (``--remote-debugging-pipe``: JSON messages separated by NUL bytes on
file descriptors 3 and 4; no network port, no extra Python package)."""

from __future__ import annotations

import fcntl
import json
import os
import select
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from typing import Any

CHROMIUM_FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--enable-unsafe-swiftshader",  # WebGL (plotly's 3D) on the software rasterizer, without a warning
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-extensions",
    "--window-size=1280,2000",
)


def find_chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


@dataclass
class PageResult:
    console: list[tuple[str, str]] = field(default_factory=list)  # (level, text) of console API calls
    exceptions: list[str] = field(default_factory=list)  # uncaught exceptions
    log: list[tuple[str, str, str]] = field(default_factory=list)  # (level, source, text) browser log entries
    values: dict[str, Any] = field(default_factory=dict)  # results of the probes

    @property
    def errors(self) -> list[str]:
        out = [f"console.{lvl}: {txt}" for lvl, txt in self.console if lvl in ("error", "assert")]
        out += [f"exception: {e}" for e in self.exceptions]
        out += [f"log {src} {lvl}: {txt}" for lvl, src, txt in self.log if lvl == "error"]
        return out


class _Pipe:
    def __init__(self, proc: subprocess.Popen[bytes], write_fd: int, read_fd: int) -> None:
        self.proc, self.wfd, self.rfd = proc, write_fd, read_fd
        self.buf = b""
        self.next_id = 0
        self.events: list[dict[str, Any]] = []

    def send(self, method: str, params: dict[str, Any] | None = None, session: str | None = None,
             timeout_s: float = 60.0) -> dict[str, Any]:  # fmt: skip
        self.next_id += 1
        msg: dict[str, Any] = {"id": self.next_id, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        os.write(self.wfd, json.dumps(msg).encode() + b"\0")
        deadline = time.monotonic() + timeout_s
        while True:
            m = self._read(deadline)
            if m.get("id") == self.next_id:
                if "error" in m:
                    raise RuntimeError(f"{method}: {m['error']}")
                return m.get("result", {})
            self.events.append(m)

    def wait_event(self, method: str, timeout_s: float) -> dict[str, Any] | None:
        deadline = time.monotonic() + timeout_s
        for i, e in enumerate(self.events):
            if e.get("method") == method:
                return self.events.pop(i)
        while time.monotonic() < deadline:
            try:
                m = self._read(deadline)
            except TimeoutError:
                return None
            if m.get("method") == method:
                return m
            self.events.append(m)
        return None

    def _read(self, deadline: float) -> dict[str, Any]:
        while b"\0" not in self.buf:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError("no reply from chromium")
            ready, _, _ = select.select([self.rfd], [], [], left)
            if ready:
                chunk = os.read(self.rfd, 1 << 20)
                if not chunk:
                    raise RuntimeError(f"chromium closed the pipe (exit code {self.proc.poll()})")
                self.buf += chunk
        raw, self.buf = self.buf.split(b"\0", 1)
        return json.loads(raw)


def open_page(
    chromium: str, url: str, probes: dict[str, str], ready: str, timeout_s: float = 120.0
) -> PageResult:
    """Load ``url``, wait until the JavaScript expression ``ready`` is true (or ``timeout_s``), evaluate
    ``probes`` (name -> JavaScript expression) and return them with every console message and error."""
    r_chrome, w_ours = os.pipe()  # chromium reads commands on fd 3
    r_ours, w_chrome = os.pipe()  # and writes replies on fd 4
    with tempfile.TemporaryDirectory(prefix="robchair-chromium-") as profile:
        args = [
            chromium,
            *CHROMIUM_FLAGS,
            f"--user-data-dir={profile}",
            "--remote-debugging-pipe",
            "about:blank",
        ]

        def _fds() -> None:  # in the child: the pipe ends become fds 3 and 4 (inheritable, kept by exec)
            high = [fcntl.fcntl(fd, fcntl.F_DUPFD, 10) for fd in (r_chrome, w_chrome)]
            os.dup2(high[0], 3)
            os.dup2(high[1], 4)

        proc = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL, preexec_fn=_fds, close_fds=False)  # fmt: skip
        os.close(r_chrome)
        os.close(w_chrome)
        pipe = _Pipe(proc, w_ours, r_ours)
        try:
            return _drive(pipe, url, probes, ready, timeout_s)
        finally:
            try:
                pipe.send("Browser.close", timeout_s=10)
            except Exception:  # the browser may already be gone
                pass
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            os.close(w_ours)
            os.close(r_ours)


def _drive(pipe: _Pipe, url: str, probes: dict[str, str], ready: str, timeout_s: float) -> PageResult:
    target = pipe.send("Target.createTarget", {"url": "about:blank"})["targetId"]
    session = pipe.send("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
    for domain in ("Runtime.enable", "Log.enable", "Page.enable"):
        pipe.send(domain, session=session)
    pipe.send("Page.navigate", {"url": url}, session=session)
    pipe.wait_event("Page.loadEventFired", timeout_s)
    res = PageResult()

    def evaluate(expr: str) -> Any:
        r = pipe.send("Runtime.evaluate", {"expression": expr, "returnByValue": True}, session=session)
        return r.get("result", {}).get("value")

    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and not evaluate(ready):
        pipe.wait_event("no.such.event", 0.25)  # collect events while waiting
    pipe.wait_event("no.such.event", 1.0)  # late console messages
    res.values = {name: evaluate(expr) for name, expr in probes.items()}
    for e in pipe.events:
        p = e.get("params", {})
        if e.get("method") == "Runtime.consoleAPICalled":
            text = " ".join(str(a.get("value", a.get("description", ""))) for a in p.get("args", []))
            res.console.append((p.get("type", ""), text))
        elif e.get("method") == "Runtime.exceptionThrown":
            d = p.get("exceptionDetails", {})
            res.exceptions.append(str(d.get("exception", {}).get("description") or d.get("text")))
        elif e.get("method") == "Log.entryAdded":
            entry = p.get("entry", {})
            res.log.append((entry.get("level", ""), entry.get("source", ""), entry.get("text", "")))
    return res
