"""The report opens in a real headless Chromium: every figure renders, nothing errors, no network.

Chromium is driven over the DevTools protocol on a pipe (``--remote-debugging-pipe``:
JSON messages separated by NUL bytes on file descriptors 3 and 4), so the test
needs no websocket package. It loads the file, checks every ``<img>`` decoded
(``complete`` and ``naturalWidth > 0``), that the console and the page logged no
error, that nothing but the file itself and ``data:`` URIs was requested, and
saves a full-page screenshot to ``test-artifacts/report.png``.

Skipped with a reason when ``chromium`` is not installed (``.ci/run`` installs
the Debian package ``chromium``).
"""

from __future__ import annotations

import base64
import json
import os
import shutil
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

import pytest
from support.png_text import png_text
from support.report_logs import no_estimate_log, realistic_log

from ptinertia.report.build import make_report
from ptinertia.report.plots import SMALLEST_TEXT_KEY

ARTIFACTS = Path(__file__).resolve().parents[3] / "test-artifacts"
CHROMIUM = next((p for p in (shutil.which(n) for n in ("chromium", "chromium-browser")) if p), None)
pytestmark = pytest.mark.skipif(
    CHROMIUM is None, reason="chromium not installed (Debian: apt-get install -y chromium)"
)

FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--remote-debugging-pipe",
]


class DevTools:
    """A minimal DevTools-protocol client on Chromium's pipe transport."""

    def __init__(self, binary: str, profile: str) -> None:
        to_child_r, self._to_child = os.pipe()
        self._from_child, from_child_w = os.pipe()

        def wire_fds() -> None:  # the pipe transport reads fd 3 and writes fd 4
            os.dup2(to_child_r, 3)
            os.dup2(from_child_w, 4)

        self.proc = subprocess.Popen(
            [binary, *FLAGS, f"--user-data-dir={profile}", "about:blank"],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            pass_fds=(3, 4),
            preexec_fn=wire_fds,
        )
        os.close(to_child_r)
        os.close(from_child_w)
        self._buf = b""
        self._id = 0
        self.events: list[dict[str, Any]] = []

    def send(
        self,
        method: str,
        params: dict[str, Any] | None = None,
        session: str | None = None,
        timeout: float = 30.0,
    ) -> dict[str, Any]:
        self._id += 1
        msg: dict[str, Any] = {"id": self._id, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        os.write(self._to_child, json.dumps(msg).encode() + b"\0")
        deadline = time.monotonic() + timeout
        while True:
            reply = self._read(deadline)
            if reply.get("id") == self._id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply.get("result", {})
            self.events.append(reply)

    def wait_event(self, method: str, timeout: float = 30.0) -> dict[str, Any]:
        for e in self.events:
            if e.get("method") == method:
                return e
        deadline = time.monotonic() + timeout
        while True:
            e = self._read(deadline)
            self.events.append(e)
            if e.get("method") == method:
                return e

    def _read(self, deadline: float) -> dict[str, Any]:
        import select

        while b"\0" not in self._buf:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError("no answer from chromium")
            ready, _, _ = select.select([self._from_child], [], [], left)
            if ready:
                chunk = os.read(self._from_child, 1 << 20)
                if not chunk:
                    raise RuntimeError("chromium closed the DevTools pipe")
                self._buf += chunk
        msg, self._buf = self._buf.split(b"\0", 1)
        return json.loads(msg)

    def close(self) -> None:
        try:
            self.send("Browser.close", timeout=5)
        except (RuntimeError, TimeoutError, OSError):
            pass
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        os.close(self._to_child)
        os.close(self._from_child)


def render(html_path: Path, screenshot: Path) -> dict[str, Any]:
    """Load the page; return images, errors and requested URLs; save a full-page screenshot."""
    assert CHROMIUM is not None
    with tempfile.TemporaryDirectory() as profile:
        dt = DevTools(CHROMIUM, profile)
        try:
            target = dt.send("Target.createTarget", {"url": "about:blank"})["targetId"]
            sid = dt.send("Target.attachToTarget", {"targetId": target, "flatten": True})[
                "sessionId"
            ]
            for domain in ("Page", "Runtime", "Log", "Network"):
                dt.send(f"{domain}.enable", session=sid)
            # a desktop-wide page, as an engineer opens it (headless defaults to 800 px)
            dt.send(
                "Emulation.setDeviceMetricsOverride",
                {"width": 1200, "height": 900, "deviceScaleFactor": 1, "mobile": False},
                session=sid,
            )
            dt.send("Page.navigate", {"url": html_path.resolve().as_uri()}, session=sid)
            dt.wait_event("Page.loadEventFired")
            images = dt.send(
                "Runtime.evaluate",
                {
                    "expression": "JSON.stringify(Array.from(document.images).map(i => "
                    "({ok: i.complete && i.naturalWidth > 0, w: i.naturalWidth, alt: i.alt, "
                    "shown: i.getBoundingClientRect().width, id: i.parentElement.id})))",
                    "returnByValue": True,
                },
                session=sid,
            )["result"]["value"]
            text = dt.send(
                "Runtime.evaluate",
                {"expression": "document.body.innerText", "returnByValue": True},
                session=sid,
            )["result"]["value"]
            metrics = dt.send("Page.getLayoutMetrics", session=sid)
            size = metrics.get("cssContentSize") or metrics["contentSize"]
            shot = dt.send(
                "Page.captureScreenshot",
                {
                    "format": "png",
                    "captureBeyondViewport": True,
                    "clip": {
                        "x": 0,
                        "y": 0,
                        "width": size["width"],
                        "height": size["height"],
                        "scale": 1,
                    },
                },
                session=sid,
            )
            screenshot.parent.mkdir(parents=True, exist_ok=True)
            screenshot.write_bytes(base64.b64decode(shot["data"]))
        finally:
            dt.close()
    events = dt.events
    errors = [e["params"] for e in events if e.get("method") == "Runtime.exceptionThrown"]
    errors += [
        e["params"]
        for e in events
        if e.get("method") == "Runtime.consoleAPICalled"
        and e["params"].get("type") in ("error", "assert")
    ]
    errors += [
        e["params"]["entry"]
        for e in events
        if e.get("method") == "Log.entryAdded" and e["params"]["entry"].get("level") == "error"
    ]
    urls = [
        e["params"]["request"]["url"]
        for e in events
        if e.get("method") == "Network.requestWillBeSent"
    ]
    return {"images": json.loads(images), "errors": errors, "urls": urls, "text": text}


@pytest.mark.parametrize("which", ["realistic", "no-estimate"])
def test_report_renders_in_chromium(tmp_path_factory: pytest.TempPathFactory, which: str) -> None:
    log = (
        realistic_log(tmp_path_factory)[0]
        if which == "realistic"
        else no_estimate_log(tmp_path_factory)
    )
    out = tmp_path_factory.mktemp("browser") / "report.html"
    report = make_report(log, out)
    shot = ARTIFACTS / ("report.png" if which == "realistic" else f"report-{which}.png")
    seen = render(out, shot)
    assert len(seen["images"]) == len(report.figures) >= (7 if which == "realistic" else 4)
    broken = [i["alt"] for i in seen["images"] if not i["ok"]]
    assert not broken, f"images that did not render: {broken}"
    assert not seen["errors"], f"console errors: {seen['errors']}"
    outside = [u for u in seen["urls"] if not (u.startswith("file:") or u.startswith("data:"))]
    assert not outside, f"the report asked the network for {outside}"
    assert shot.stat().st_size > 20_000
    # text in the figures as the page shows them: the smallest font the figure was drawn
    # with (written into its PNG), scaled by the shown / natural width
    for img in seen["images"]:
        name = img["id"].removeprefix("fig-")
        drawn_px = float(png_text(report.figures[name])[SMALLEST_TEXT_KEY])
        assert drawn_px * img["shown"] / img["w"] >= 9.0, (name, drawn_px, img)
    # an unbalance the estimator did not detect is shown without an angle
    for line in seen["text"].splitlines():
        if "unbalance" in line and "not detected" in line:
            assert "deg" not in line, line


def test_a_broken_image_would_be_caught(tmp_path: Path) -> None:
    """The check can fail: an undecodable PNG and a console error are both seen."""
    from matplotlib.figure import Figure

    from ptinertia.report.plots import png

    good = base64.b64encode(png(Figure(figsize=(1, 1)))).decode()
    page = tmp_path / "broken.html"
    page.write_text(
        '<!DOCTYPE html><html><body><img alt="bad" src="data:image/png;base64,iVBORw0KGgoAAAAN">'
        f'<img alt="good" src="data:image/png;base64,{good}">'
        "<script>console.error('boom')</script></body></html>",
        encoding="utf-8",
    )
    seen = render(page, tmp_path / "broken.png")
    assert [i["alt"] for i in seen["images"] if not i["ok"]] == ["bad"]
    assert seen["errors"], "a console error must be seen"
