"""Running one bad-input case as a subprocess and describing what it did: exit code, stderr,
and the state of the output folder before and after (for benchmarks/fault_injection.py)."""

from __future__ import annotations

import hashlib
import json
import re
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from benchmarks.common import ROOT

TRACEBACK = "Traceback (most recent call last)"
#: Options every smoke fit of the table shares, shown as ``[smoke]`` in the command column.
SMOKE_FIT = re.compile(r"--config configs/trainer/cpu_smoke\.yaml --config configs/(\w+)/small\.yaml "
                       r"--data\.data_dir \S+ (.*)--trainer\.default_root_dir \S+ "
                       r"--trainer\.logger\.init_args\.save_dir \S+ "
                       r"--trainer\.enable_progress_bar false")


@dataclass(frozen=True)
class Row:
    """One line of the fault-injection table."""

    case: str
    command: str
    exit_code: int | None
    stderr_lines: int
    last_line: str
    before: str
    after: str

    def markdown(self) -> str:
        cells = [self.case, f"`{self.command}`", str(self.exit_code), str(self.stderr_lines), self.last_line,
                 self.before, self.after]
        return "| " + " | ".join(c.replace("|", "\\|").replace("\n", " ") for c in cells) + " |"


@dataclass(frozen=True)
class Finished:
    """What a subprocess left: its exit code (None: killed after the timeout) and stderr text."""

    exit_code: int | None
    stderr: str

    def stderr_summary(self) -> tuple[int, str]:
        """(number of non-empty stderr lines, the last one; 'traceback: <last line>' when it holds one)."""
        lines = [ln for ln in self.stderr.splitlines() if ln.strip()]
        last = lines[-1].strip() if lines else "-"
        if TRACEBACK in self.stderr:
            last = f"traceback: {last}"
        return len(lines), last[:200]


def fingerprint(folder: Path) -> dict[str, str]:
    """sha256 of every file under ``folder`` by relative path ({} when it does not exist)."""
    if not folder.exists():
        return {}
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def describe_folder(folder: Path) -> str:
    """A short account of an output folder: its run summary (status, frames) or its file count."""
    if not folder.exists():
        return "nothing written"
    files = [p for p in folder.rglob("*") if p.is_file()]
    if not files:
        return "empty folder"
    summary = folder / "summary.json"
    if summary.is_file():
        try:
            s = json.loads(summary.read_text())
        except ValueError:
            return f"{len(files)} files, unreadable summary.json"
        mesh = ", mesh" if (folder / "mesh.ply").is_file() else ", no mesh"
        return f"status {s.get('status')}, {s.get('frames')} frames{mesh}"
    return f"{len(files)} files"


def stray_siblings(folder: Path) -> list[str]:
    """Hidden staging / trash folders left beside ``folder`` (``.NAME.*``)."""
    if not folder.parent.is_dir():
        return []
    return sorted(p.name for p in folder.parent.iterdir() if p.name.startswith(f".{folder.name}."))


def after_state(folder: Path, before: dict[str, str]) -> str:
    """The folder after a case, compared with its fingerprint ``before``."""
    now = fingerprint(folder)
    text = describe_folder(folder)
    if before and now == before:
        text = f"OUT unchanged ({text})"
    elif before:
        text = f"OUT changed: {text}"
    stray = stray_siblings(folder)
    return text + (f"; left beside it: {', '.join(stray)}" if stray else "")


def short_command(cmd: Sequence[str], work: Path) -> str:
    """``cmd`` as a reader would type it: ``python`` for the interpreter, ``W/`` for the work folder."""
    text = " ".join(str(c) for c in cmd).replace(sys.executable, "python").replace(str(work), "W")
    return SMOKE_FIT.sub(lambda m: f"[smoke {m.group(1)}] {m.group(2)}".rstrip(), text)


def run_to_end(cmd: Sequence[str], timeout_s: float = 600.0) -> Finished:
    """Run ``cmd`` from the repository root to its end."""
    try:
        r = subprocess.run(list(cmd), cwd=ROOT, capture_output=True, text=True, timeout=timeout_s, check=False)
    except subprocess.TimeoutExpired as exc:
        return Finished(None, (exc.stderr or b"").decode(errors="replace") + "\n(killed after the timeout)")
    return Finished(r.returncode, r.stderr)


def run_interrupted(cmd: Sequence[str], started: Callable[[], bool], delay_s: float = 0.5,
                    timeout_s: float = 600.0) -> Finished:
    """Run ``cmd``, send SIGINT ``delay_s`` seconds after ``started()`` first holds, wait for its end.

    A process that ends before it is seen starting is reported as it ended (stderr says so).
    """
    proc = subprocess.Popen(list(cmd), cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + timeout_s
    note = ""
    while proc.poll() is None and not started() and time.monotonic() < deadline:
        time.sleep(0.05)
    if proc.poll() is None:
        time.sleep(delay_s)
        proc.send_signal(signal.SIGINT)
    else:
        note = "\n(ended before SIGINT could be sent)"
    try:
        _, err = proc.communicate(timeout=max(1.0, deadline - time.monotonic()))
    except subprocess.TimeoutExpired:
        proc.kill()
        _, err = proc.communicate()
        return Finished(None, err + "\n(killed after the timeout)")
    return Finished(proc.returncode, err + note)


def make_row(case: str, cmd: Sequence[str], work: Path, out: Path, finished: Finished, before_text: str,
             before: dict[str, str]) -> Row:
    """The table row of a case that ran ``cmd`` with output folder ``out``; its stderr is kept
    beside ``out`` (``stderr.txt``)."""
    if out.parent.is_dir():
        (out.parent / "stderr.txt").write_text(finished.stderr)
    n, last = finished.stderr_summary()
    return Row(case, short_command(cmd, work), finished.exit_code, n, last, before_text, after_state(out, before))


def run_case(case: str, cmd: Sequence[str], work: Path, out: Path) -> Row:
    """Run ``cmd`` to its end; the row compares ``out`` before and after."""
    before = fingerprint(out)
    before_text = describe_folder(out)
    return make_row(case, cmd, work, out, run_to_end(cmd), before_text, before)
