"""The live page (c3f_slam/live/page.html, live.js) in headless Chromium while a producer thread feeds
a LiveState as a run would: a synthetic withdrawal through a straight tube of radius 2 cm.

How the browser is driven, and why: ``--dump-dom`` (tests/browser.py) dumps at the load event unless
``--virtual-time-budget`` is given, and virtual time fast-forwards the page's timers (it pauses only
while a fetch is pending): 20 s of the page's polling pass in about half a second of real time,
before a producer thread in real time has published anything worth seeing, and ``--timeout`` does not
delay the dump. So the test speaks the DevTools protocol over a pipe (``--remote-debugging-pipe``:
NUL-terminated JSON on fds 3 and 4, no port, no websocket) and waits in real time for the page's
self-test result (``<pre id="live-selftest">``, ``#selftest``: written once a frame was shown and wall
rows and an alert were received). The protocol also gives the browser's own error log (a failed
resource load is no JavaScript error) and a screenshot. Chromium 156 sends IP-literal hosts through
``--host-resolver-rules`` too, so the rule here maps every name but 127.0.0.1 to NOTFOUND.

``python -m tests.test_live_page [PNG]`` saves a screenshot of the page during such a feed
(default /tmp/live_page.png).
"""

from __future__ import annotations

import base64
import fcntl
import json
import math
import os
import select
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from c3f_slam.live.server import LiveServer
from c3f_slam.live.state import LiveState, WallRow
from tests.browser import FLAGS, chromium

W, H = 320, 256
K = [[240.0, 0.0, 160.0], [0.0, 240.0, 128.0], [0.0, 0.0, 1.0]]
A, CELL, SEGMENT, RADIUS, THRESHOLD = 36, 0.005, 0.05, 0.02, 0.2
STEP = 0.001  #: metres the scope moves per frame
LOOPBACK_ONLY = "--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE 127.0.0.1"


class Browser:
    """Headless Chromium on the DevTools protocol over a pipe: ``call(method, params)`` on the page;
    ``errors`` the browser's error log entries and uncaught exceptions."""

    def __init__(self, width: int = 1280, height: int = 800) -> None:
        self._profile = tempfile.TemporaryDirectory()
        to_browser, self._out = os.pipe()
        self._in, from_browser = os.pipe()
        # the pipe's ends become the browser's fds 3 and 4 by a small Python exec wrapper (no preexec_fn:
        # other threads are running); copied above 10 first so that the dup2 calls cannot clash
        child = [fcntl.fcntl(fd, fcntl.F_DUPFD, 10) for fd in (to_browser, from_browser)]
        os.close(to_browser)
        os.close(from_browser)
        flags = [f for f in FLAGS if not f.startswith("--host-resolver-rules")] + [LOOPBACK_ONLY]
        args = [*flags, f"--user-data-dir={self._profile.name}", "--remote-debugging-pipe",
                f"--window-size={width},{height}", "about:blank"]
        wrapper = (f"import os, sys; os.dup2({child[0]}, 3); os.dup2({child[1]}, 4); os.close({child[0]}); "
                   f"os.close({child[1]}); os.execv(sys.argv[1], sys.argv[1:])")
        self.proc = subprocess.Popen([sys.executable, "-c", wrapper, chromium(), *args], pass_fds=child,
                                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        for fd in child:
            os.close(fd)
        self._buf, self._id, self.errors = b"", 0, []
        self._session = None
        targets = self.call("Target.getTargets")["targetInfos"]
        page = next(t["targetId"] for t in targets if t["type"] == "page")
        self._session = self.call("Target.attachToTarget", {"targetId": page, "flatten": True})["sessionId"]
        for method in ("Log.enable", "Runtime.enable"):
            self.call(method)
        self.call("Emulation.setDeviceMetricsOverride", {"width": width, "height": height, "deviceScaleFactor": 1,
                                                         "mobile": False})

    def _message(self, deadline: float) -> dict:
        while b"\0" not in self._buf:
            if not select.select([self._in], [], [], max(0.0, deadline - time.time()))[0]:
                raise TimeoutError("the browser did not answer")
            chunk = os.read(self._in, 1 << 16)
            if not chunk:
                raise RuntimeError("the browser closed its pipe")
            self._buf += chunk
        raw, self._buf = self._buf.split(b"\0", 1)
        return json.loads(raw)

    def call(self, method: str, params: dict | None = None, timeout: float = 30) -> dict:
        self._id += 1
        msg = {"id": self._id, "method": method, "params": params or {}}
        if self._session:
            msg["sessionId"] = self._session
        os.write(self._out, json.dumps(msg).encode() + b"\0")
        deadline = time.time() + timeout
        while True:
            m = self._message(deadline)
            if m.get("method") == "Log.entryAdded" and m["params"]["entry"]["level"] == "error":
                entry = m["params"]["entry"]
                self.errors.append(f"{entry.get('url', '')}: {entry['text']}")
            elif m.get("method") == "Runtime.exceptionThrown":
                self.errors.append(json.dumps(m["params"]["exceptionDetails"])[:500])
            if m.get("id") == self._id:
                if "error" in m:
                    raise RuntimeError(f"{method}: {m['error']}")
                return m["result"]

    def evaluate(self, expression: str):
        return self.call("Runtime.evaluate", {"expression": expression, "returnByValue": True})["result"].get("value")

    def screenshot(self, png: Path) -> None:
        png.write_bytes(base64.b64decode(self.call("Page.captureScreenshot", {"format": "png"})["data"]))

    def close(self) -> None:
        try:
            self._session = None
            self.call("Browser.close", timeout=5)
        except (OSError, RuntimeError, TimeoutError):
            pass
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        os.close(self._in)
        os.close(self._out)
        self._profile.cleanup()

    def __enter__(self) -> Browser:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def tissue_mask() -> np.ndarray:
    yy, xx = np.mgrid[:H, :W]
    return np.hypot((xx - W / 2) / (W * 0.55), (yy - H / 2) / (H * 0.55)) < 1  # the corners are border


def live_state() -> LiveState:
    return LiveState(source={"name": "synthetic_withdrawal.mp4", "kind": "video", "rate_fps": 30.0},
                     camera={"K": K, "width": W, "height": H}, tissue_mask=tissue_mask(),
                     wall={"cell_length_m": CELL, "angle_bins": A, "segment_m": SEGMENT, "threshold": THRESHOLD})


def synthetic_frame(i: int) -> np.ndarray:
    """A pinkish frame with a dark lumen in the centre and folds that move with ``i``."""
    yy, xx = np.mgrid[:H, :W]
    r = np.hypot((xx - W / 2) / (W / 2), (yy - H / 2) / (H / 2))
    light = 0.15 + 0.85 * np.clip(r, 0, 1) ** 0.7
    folds = 0.85 + 0.15 * np.sin(18 * r - 0.3 * i)
    rgb = np.stack([225 * light * folds, 125 * light * folds, 112 * light * folds], axis=-1)
    return np.clip(rgb, 0, 255).astype(np.uint8)


def unseen(i: int, j: int) -> bool:
    """The synthetic wall's unseen cells: a patch at 2 o'clock in segment 2, a speck in segment 1."""
    return (11 <= i <= 17 and 3 <= j <= 16) or (2 <= i <= 3 and 20 <= j <= 23)


def wall_row(i: int, newest: bool) -> WallRow:
    theta = -np.pi + (np.arange(A) + 0.5) * 2 * np.pi / A
    s = (i + 0.5) * CELL
    radius = RADIUS * (1 + 0.08 * np.sin(3 * theta + 40 * s))
    if newest:
        radius[:2] = np.nan
    observed = np.array([not unseen(i, j) for j in range(A)])
    colour = np.stack([200 + 30 * np.sin(theta), 110 + 20 * np.cos(50 * s) + 0 * theta, 100 + 0 * theta], axis=-1)
    return WallRow(i=i, centre=(0.0, 0.0, s), N=(1.0, 0.0, 0.0), B=(0.0, 1.0, 0.0), radius=radius, observed=observed,
                   measured=observed, colour=colour.astype(np.uint8))


def feed(state: LiveState, stop: threading.Event, fps: float = 60.0, frames: int = 100_000) -> None:
    """Publishes a synthetic run at ``fps`` frames per second until ``stop`` (or ``frames``)."""
    rng = np.random.default_rng(0)
    images = [synthetic_frame(k) for k in range(8)]
    dropped = taken = 0
    alerted = False
    t0 = time.time()
    f = 0
    while f < frames and not stop.is_set():
        time.sleep(max(0.0, t0 + f / fps - time.time()))
        if f % 25 == 24:  # the source delivered two frames the run had no time for
            state.drop_frames(f, f + 1)
            dropped += 2
            f += 2
            continue
        z = 0.02 + f * STEP
        kind = ("lone" if f == 0 else "lost" if 60 <= f <= 62 else "rejoined" if f == 63 else "blurred" if f % 17 == 5
                else "keyframe" if f % 10 == 0 else "extended")
        placed = kind not in ("lost", "blurred")
        pose = np.eye(4)
        pose[:3, 3] = (0.001 * math.sin(f / 9), 0.001 * math.cos(f / 7), z)
        state.publish_frame(index=f, timestamp=f / 30, captured_at=time.time() - 0.03, decision=kind,
                            rgb=images[f % len(images)], pose=pose if placed else None)
        taken += 1
        newest = int((z + 0.01) / CELL)
        state.update_wall([wall_row(i, i == newest) for i in range(0 if f == 0 else max(0, newest - 3), newest + 1)])
        if f % 5 == 0:
            n = 150
            theta = rng.uniform(-np.pi, np.pi, n)
            s = z + rng.uniform(-0.01, 0.01, n)
            xyz = np.stack([RADIUS * np.cos(theta), RADIUS * np.sin(theta), s], axis=-1)
            state.add_map_points(xyz, rng.integers((170, 80, 70), (240, 140, 130), (n, 3)).astype(np.uint8))
        segments = []
        for k in range(int((newest + 1) * CELL / SEGMENT) + 1):
            rows = range(k * 10, min((k + 1) * 10, newest + 1))
            share = sum(unseen(i, j) for i in rows for j in range(A)) / (10 * A)
            segments.append({"index": k, "start_m": k * SEGMENT, "end_m": (k + 1) * SEGMENT, "unseen_share": share,
                             "state": "current" if k * SEGMENT <= z < (k + 1) * SEGMENT else "passed"})
        state.set_segments(segments)
        if not alerted and z > 2 * SEGMENT + 0.005:
            state.add_alert({"segment": 1, "start_m": SEGMENT, "end_m": 2 * SEGMENT,
                             "unseen_share": segments[1]["unseen_share"],
                             "gap": {"clock": 2, "s_from_m": 0.055, "s_to_m": 0.09, "area_cm2": 3.1}, "frame": f,
                             "time": f / 30})
            alerted = True
        elapsed = time.time() - t0
        state.set_rates(source_fps=30.0, processed_fps=taken / elapsed if elapsed > 0 else None, dropped=dropped,
                        taken=taken)
        f += 1


def run_page(fragment: str, until, timeout: float = 60.0, png: Path | None = None):
    """Serves a fed LiveState, opens the page (``fragment`` appended to its address), returns
    (``until(browser)`` once truthy, the browser's errors); saves a screenshot to ``png`` then."""
    state = live_state()
    stop = threading.Event()
    producer = threading.Thread(target=feed, args=(state, stop), daemon=True)
    with LiveServer(state) as server, Browser() as browser:
        producer.start()
        try:
            browser.call("Page.navigate", {"url": server.url + fragment})
            deadline = time.time() + timeout
            while not (result := until(browser)):
                assert time.time() < deadline, "the page did not get there in time"
                time.sleep(0.25)
            if png is not None:
                browser.screenshot(png)
            return result, browser.errors
        finally:
            stop.set()
            producer.join(timeout=10)


def selftest_result(browser: Browser) -> dict | None:
    text = browser.evaluate("(document.getElementById('live-selftest') || {}).textContent || ''")
    return json.loads(text) if text else None


def test_page_shows_a_live_run():
    chromium()
    res, browser_errors = run_page("#selftest", selftest_result)
    assert res["errors"] == [] and browser_errors == []
    assert res["frame_loaded"] and res["frame_index"] is not None
    assert res["map_points"] > 0 and res["wall_rows"] > 0
    assert res["canvas_nonbackground_pixels"] > 2000 and res["unrolled_nonbackground_pixels"] > 2000
    assert res["alerts"] >= 1 and res["alert_text"].startswith("Segment 2 (5-10 cm): 27 % of the wall unseen")
    assert "gap at 2 o'clock, 6-9 cm" in res["alert_text"]
    assert res["timeline_entries"] > 0


def main(png: Path) -> None:
    """Saves a screenshot of the page (1280x800) once an alert is shown and the run went on a while."""
    shown = "!document.getElementById('banner').hidden && document.querySelectorAll('.seg').length >= 3"
    run_page("", lambda b: b.evaluate(shown), png=png)
    print(png)


if __name__ == "__main__":
    main(Path(sys.argv[1] if len(sys.argv) > 1 else "/tmp/live_page.png"))
