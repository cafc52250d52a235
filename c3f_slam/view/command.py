"""The ``view`` command: write the view of a run folder, say what was written, open the page.

The page is opened with Python's ``webbrowser`` only where a graphical browser can exist (a
display on Linux: ``DISPLAY`` or ``WAYLAND_DISPLAY``; macOS; Windows), so that on a server or
in CI it never starts a text-mode browser and never waits.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

from c3f_core.errors import InputError
from c3f_slam.view.settings import ViewSettings


def can_open_browser() -> bool:
    """Whether a graphical browser can be opened from here."""
    if sys.platform in ("darwin", "win32"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def view_command(out: str | Path, *, gt: str | Path | None, sequence: str | Path | None, videos: bool,
                 open_page: bool, progress: bool, settings: ViewSettings | None = None) -> int:
    """Write ``out``'s view with ``settings`` (:func:`c3f_slam.view.build.write_view`), print one
    line per file, open the page."""
    from c3f_slam.view.build import PAGE, RECORD, write_view

    run = Path(out)
    if not run.is_dir():
        raise InputError(f"{run}: run folder not found")
    res = write_view(run, gt=gt, videos=videos, sequence=sequence, settings=settings, progress=progress)
    print(f"{run / PAGE}: {res.page_bytes / 1e6:.1f} MB, {res.triangles:,} triangles")
    for name, v in res.videos.items():
        ms = v["ms_per_frame"]
        print(f"{run / name}: {v['frames']} frames" + (f", {ms:.1f} ms per rendered frame" if ms else ""))
    if videos and not res.videos:
        print("no videos: the run has no mesh or no trajectory")
    print(f"{run / RECORD}: the settings used (replay: --config {run / RECORD})")
    if open_page and can_open_browser():
        import webbrowser

        webbrowser.open((run / PAGE).resolve().as_uri())
    return 0
