"""The rule every command line keeps with bad input, as the bad-input tests check it.

Bad input ends the command with exit status 2 and one stderr line that starts ``error: `` and
names the file or option; it never destroys or mixes earlier outputs: the output folder is
fingerprinted before and after (every file's SHA-256), and no staging or trash folder is left
beside it (``.NAME.*``). Ctrl-C gives one line, exit status 130 and a defined state.
"""

from __future__ import annotations

import hashlib
import json
import signal
import subprocess
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def fingerprint(folder: Path) -> dict[str, str] | None:
    """SHA-256 of every file under ``folder`` by relative path (None: no such folder)."""
    if not folder.exists():
        return None
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def left_beside(folder: Path) -> list[str]:
    """Hidden staging / trash folders left beside ``folder`` (``.NAME.*``)."""
    parent = folder.parent
    return sorted(p.name for p in parent.iterdir() if p.name.startswith(f".{folder.name}.")) if parent.is_dir() else []


def error_line(stderr: str, only: bool = True) -> str:
    """The one ``error: `` line of ``stderr``: the last line, and the only one starting so; with
    ``only`` the only line at all (a command whose libraries log to stderr passes ``only=False``)."""
    lines = [line for line in stderr.splitlines() if line.strip()]
    errors = [line for line in lines if line.startswith("error: ")]
    assert len(errors) == 1 and lines[-1] == errors[0], lines
    assert not only or len(lines) == 1, lines
    return errors[0]


@dataclass(frozen=True)
class Case:
    """One bad input: the command (``main``, called with ``argv``), its output folder ``out``, what
    its error line names, ``run_after``: None when ``out`` must be as it was (or stay absent), else
    the summary.json items of the run folder the command leaves there (a SLAM run records its own
    failure), and files that must not exist afterwards (``absent``)."""

    main: Callable[[list[str]], int | None]
    argv: list[str]
    out: Path
    names: tuple[str, ...]
    run_after: dict | None = None
    absent: tuple[Path, ...] = ()


def check_refused(case: Case, capsys, only: bool = True) -> None:
    """Run ``case`` and check the rule: exit status 2 (returned or raised), one error line
    (:func:`error_line`) naming each of ``case.names``, ``out`` as it was or the run ``run_after``
    says (no mesh), nothing left beside ``out``, nothing of ``case.absent``."""
    before = fingerprint(case.out)
    capsys.readouterr()
    try:
        code = case.main(case.argv)
    except SystemExit as exc:
        code = exc.code
    assert code == 2
    line = error_line(capsys.readouterr().err, only)
    assert all(name in line for name in case.names), (case.names, line)
    if case.run_after is None:
        assert fingerprint(case.out) == before
    else:
        summary = json.loads((case.out / "summary.json").read_text())
        assert {k: summary.get(k) for k in case.run_after} == case.run_after
        assert not (case.out / "mesh.ply").exists()
    assert left_beside(case.out) == [] and not any(p.exists() for p in case.absent)


def default_sigint() -> None:
    """In the child before it starts: Ctrl-C raises KeyboardInterrupt there, whatever the parent ignores."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def interrupt(cmd: Sequence[str], started: Callable[[], bool], delay_s: float,
              timeout_s: float = 300.0) -> tuple[int, str]:
    """Run ``cmd`` from the repository root and send it SIGINT (Ctrl-C) ``delay_s`` seconds after
    ``started()`` first holds; returns its exit status and stderr. Fails when it ends first."""
    # SIGINT's default action in the child: a shell without job control starts background jobs with
    # SIGINT ignored, and the child would inherit that (``nohup make test &`` made the run end with 0)
    proc = subprocess.Popen(list(cmd), cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            preexec_fn=default_sigint)
    try:
        deadline = time.monotonic() + timeout_s
        while proc.poll() is None and not started():
            assert time.monotonic() < deadline, "the command did not start in time"
            time.sleep(0.05)
        time.sleep(delay_s)
        assert proc.poll() is None, f"the command ended before Ctrl-C: {proc.stderr.read()[-2000:]}"
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=timeout_s)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    return proc.returncode, err
