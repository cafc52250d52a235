"""Headless Chromium on a page's self-test (``PAGE#selftest``, c3f_slam/view/viewer.js): WebGL by
SwiftShader on the CPU, every host name unresolvable (no network), the DOM dumped after the
page's timers ran; the self-test's JSON is read back from it."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import tempfile
from pathlib import Path

import pytest

BROWSERS = ("chromium", "chromium-browser", "google-chrome")
FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader", "--hide-scrollbars",
         "--host-resolver-rules=MAP * ~NOTFOUND")


def chromium() -> str:
    """The browser's path; the calling test is skipped, saying why, when there is none."""
    for name in BROWSERS:
        path = shutil.which(name)
        if path:
            return path
    pytest.skip("no chromium on PATH (.ci/run installs Debian's chromium; apt-get install chromium)")


def _run(args: list[str], page: Path, suffix: str, timeout: float) -> str:
    with tempfile.TemporaryDirectory() as profile:
        proc = subprocess.run([chromium(), *FLAGS, f"--user-data-dir={profile}", *args,
                               page.resolve().as_uri() + suffix], capture_output=True, text=True, timeout=timeout)
    return proc.stdout


def selftest(page: Path, budget_ms: int = 30000, timeout: float = 180) -> dict:
    """The self-test's result of ``page``: ``views`` (per viewer: pixels, drawn, layers: {id:
    {changed, restored}}), ``errors`` (console errors), ``videos``."""
    dom = _run(["--window-size=1280,900", f"--virtual-time-budget={budget_ms}", "--dump-dom"], page, "#selftest",
               timeout)
    found = re.search(r'<pre id="c3f-selftest">(.*?)</pre>', dom, re.S)
    assert found, f"no self-test result in the page's DOM ({len(dom)} characters dumped)"
    return json.loads(found.group(1).replace("&quot;", '"').replace("&lt;", "<").replace("&gt;", ">")
                      .replace("&amp;", "&"))


def screenshot(page: Path, png: Path, width: int = 1280, height: int = 900, budget_ms: int = 15000) -> None:
    """A PNG of ``page`` as a browser window of ``width`` x ``height`` shows it."""
    _run([f"--window-size={width},{height}", f"--virtual-time-budget={budget_ms}", f"--screenshot={png.resolve()}"],
         page, "", 180)
