"""How long README's second command takes on a fresh clone: ``make test``, alone and beside a CPU-heavy process.

The protocol clones the repository's committed state (``HEAD``) into the work folder, sets it up
as README says (``make setup``: a virtual environment and ``pip install -e ".[dev]"``, timed on
its own), then runs ``make test`` (``ruff check .`` and the test suite without the tests marked
``long``) twice in that clone: once alone, once while ``load`` other processes keep CPU cores
busy (a pure-Python loop each: the machine shared with another job). Per run: the wall time, the
test count and pytest's own summary line. ``make test-e2e`` (the ``long`` tests) is timed once,
alone, with ``--set e2e=true``. Nothing of the clone is kept after a run unless ``--keep``.

    python -m benchmarks.protocols.test_time --report benchmarks/results/test_time.md
    python -m benchmarks.protocols.test_time --set load=2 --set e2e=true --report /tmp/test_time.md

Settings (``--print-config``: each with its default and meaning): :class:`Settings`.
"""

from __future__ import annotations

import multiprocessing as mp
import re
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from benchmarks.common import RESULTS, ROOT, WORK
from benchmarks.common.protocol_cli import REPORT_HELP, ProtocolCli
from benchmarks.common.report import Report

SUMMARY = re.compile(r"=+ (.*(?:passed|failed).*) in ([\d.]+)s")


def busy(stop) -> None:
    """Keep one core busy until ``stop`` is set (the load beside a run)."""
    x = 0
    while not stop.is_set():
        for _ in range(100_000):
            x += 1


def timed(cmd: list[str], cwd: Path, log: Path) -> dict:
    """Run ``cmd`` in ``cwd`` (output to ``log``); wall seconds, return code and pytest's summary."""
    t0 = time.perf_counter()
    with log.open("w") as fh:
        rc = subprocess.run(cmd, cwd=cwd, stdout=fh, stderr=subprocess.STDOUT).returncode
    seconds = time.perf_counter() - t0
    found = SUMMARY.findall(log.read_text())
    return {"command": " ".join(cmd), "rc": rc, "seconds": round(seconds, 1),
            "pytest": found[-1][0] if found else None, "pytest_seconds": float(found[-1][1]) if found else None}


def run_loaded(cmd: list[str], cwd: Path, log: Path, load: int) -> dict:
    """:func:`timed` while ``load`` processes keep a core busy each."""
    stop = mp.Event()
    workers = [mp.Process(target=busy, args=(stop,), daemon=True) for _ in range(load)]
    for w in workers:
        w.start()
    try:
        return timed(cmd, cwd, log)
    finally:
        stop.set()
        for w in workers:
            w.join(timeout=10)


def _minutes(s: float | None) -> str:
    return "-" if s is None else f"{int(s // 60)}:{int(round(s % 60)):02d}"


@dataclass(frozen=True)
class Settings:
    """What test_time measures."""

    load: int = 1  #: busy processes beside the loaded run of make test
    e2e: bool = False  #: also time make test-e2e once, alone


CLI = ProtocolCli("test_time", Settings, __doc__, example="load=2")


def main(argv: list[str] | None = None) -> int:
    ap = CLI.parser()
    ap.add_argument("--keep", action="store_true", help="keep the clone in the work folder")
    ap.add_argument("--work", type=Path, default=WORK / "test_time", help="where the clone is made")
    ap.add_argument("--report", type=Path, default=RESULTS / "test_time.md", help=REPORT_HELP)
    args, settings = CLI.parse(ap, argv)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                            text=True, check=True).stdout.strip()
    clone = args.work / "clone"
    shutil.rmtree(clone, ignore_errors=True)
    args.work.mkdir(parents=True, exist_ok=True)
    subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
    runs = {"setup (make setup)": timed(["make", "setup"], clone, args.work / "setup.log"),
            "make test, alone": timed(["make", "test"], clone, args.work / "test_alone.log"),
            f"make test, {settings.load} busy process(es) beside it": run_loaded(
                ["make", "test"], clone, args.work / "test_loaded.log", settings.load)}
    if settings.e2e:
        runs["make test-e2e, alone"] = timed(["make", "test-e2e"], clone, args.work / "test_e2e.log")
    if not args.keep:
        shutil.rmtree(clone, ignore_errors=True)
    rows = [f"| {name} | {r['rc']} | {_minutes(r['seconds'])} | {r['pytest'] or '-'} | "
            f"{_minutes(r['pytest_seconds'])} |" for name, r in runs.items()]
    body = [f"A fresh clone of commit {commit} on this machine (2 CPU cores, no GPU). `make test` runs `ruff check .` "
            "and `python -m pytest -n 2 --durations=15 -m \"not slow and not long\"`; the wall time includes "
            "both and the collection; the set-up (a virtual environment and `pip install -e \".[dev]\"` from the "
            "package registries) is timed apart. The loaded run has that many pure-Python busy loops beside it.",
            "", "| run | exit | wall (min:s) | pytest's summary | pytest's time (min:s) |", "|---|---|---|---|---|",
            *rows]
    Report(__file__, "make test on a fresh clone", argv).publish(args.report, body, settings,
                                                                 {"commit": commit, "runs": runs}, options=args)
    print("\n".join(body))
    return 0 if all(r["rc"] == 0 for r in runs.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
