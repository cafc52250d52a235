"""Progress of the demo: the training step read from the file the training callback writes
(:class:`c3f_demo.progress_callback.ProgressFile`, a module of its own so that the demo's own
process never imports Lightning), and the console line per stage (fraction, elapsed, ETA) with
the per-stage time table at the end."""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path


def read_step_fraction(path: Path) -> float | None:
    """Fraction done from a :class:`~c3f_demo.progress_callback.ProgressFile` file (None when absent or unreadable)."""
    try:
        step, total = (int(x) for x in path.read_text().split())
    except (OSError, ValueError):
        return None
    return min(step / total, 1.0) if total > 0 else None


def clock(seconds: float) -> str:
    """``M:SS`` (or ``H:MM:SS``)."""
    s = int(round(max(seconds, 0.0)))
    h, m = divmod(s // 60, 60)
    return f"{h}:{m:02d}:{s % 60:02d}" if h else f"{m}:{s % 60:02d}"


class StageLine:
    """One console line per stage: ``[i/n] name  bar  pct  elapsed  ETA``, redrawn each second on a
    terminal (one line at start and end otherwise). The fraction comes from ``probe`` when it
    knows it, else from the elapsed time against ``estimate_s`` (the ETA is then marked ``~``)."""

    def __init__(self, index: int, total: int, name: str, estimate_s: float,
                 probe: Callable[[], float | None] | None = None, stream=None) -> None:
        self.label = f"[{index}/{total}] {name:<15}"
        self.estimate_s, self.probe = max(estimate_s, 1.0), probe
        self.stream = stream or sys.stdout
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.start = time.monotonic()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def text(self) -> str:
        elapsed = time.monotonic() - self.start
        known = self.probe() if self.probe else None
        frac = known if known is not None else min(elapsed / self.estimate_s, 0.99)
        if known and known > 0.02:
            eta = f"ETA {clock(elapsed / known - elapsed)}"
        else:
            eta = f"ETA ~{clock(max(self.estimate_s - elapsed, 0))}"
        bar = "#" * int(20 * frac) + "." * (20 - int(20 * frac))
        return f"{self.label} {bar} {100 * frac:3.0f}%  {clock(elapsed)} elapsed, {eta}"

    def __enter__(self) -> StageLine:
        if self.tty:
            self._thread = threading.Thread(target=self._redraw, daemon=True)
            self._thread.start()
        else:
            print(f"{self.label} started (estimate {clock(self.estimate_s)})", file=self.stream, flush=True)
        return self

    def _redraw(self) -> None:
        while not self._stop.wait(1.0):
            print("\r" + self.text(), end="", file=self.stream, flush=True)

    def __exit__(self, *exc) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            print("\r\033[K", end="", file=self.stream)
        if exc[0] is None:
            print(f"{self.label} done in {clock(time.monotonic() - self.start)}", file=self.stream, flush=True)
        elif self.tty:
            print(file=self.stream, flush=True)


def time_table(rows: list[tuple[str, float, str]]) -> str:
    """The per-stage table printed at the end: (stage, seconds, status)."""
    lines = [f"{'stage':<15} {'time':>8}  status", "-" * 40]
    lines += [f"{name:<15} {clock(sec):>8}  {status}" for name, sec, status in rows]
    lines.append(f"{'total':<15} {clock(sum(r[1] for r in rows)):>8}")
    return "\n".join(lines)
