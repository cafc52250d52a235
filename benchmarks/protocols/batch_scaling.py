"""Wall time of ``python -m c3f_slam batch`` over the 7 coverage cases with 1 and with 2 (or
more) workers: how much a data set gains from running its sequences side by side.

The cases are those of ``coverage_accuracy`` (simulator colon, seq1 seed 7, 300 frames,
128 px; generated under ``--work`` unless there), listed in one list file. Each worker count
runs the whole batch into its own folder (``--overwrite``: every run made again, none skipped),
with ground-truth depth and SIFT at default settings (mesh and coverage on), the workers
sharing the machine's cores equally (the batch's default thread budget). ``repeats`` runs of
each, alternating so that machine noise hits all alike; the median wall time is reported, with
its ratio to 1 worker, and each batch's registered share and mean ATE (parallel runs must give
the runs of a single worker).

    python -m benchmarks.protocols.batch_scaling --set workers=1,2

Writes benchmarks/results/batch_scaling.md and its .json. Settings (``--print-config``: each with
its default and meaning): :class:`Settings`.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from benchmarks.common import RESULTS, ROOT, WORK
from benchmarks.common.protocol_cli import REPORT_HELP, ProtocolCli, check_not_empty
from benchmarks.common.report import Report
from benchmarks.common.simulate import ensure_sequence
from benchmarks.protocols.coverage_accuracy import CASES, case_sequence


@dataclass(frozen=True)
class Settings:
    """What batch_scaling measures."""

    workers: tuple[int, ...] = (1, 2)  #: worker counts compared (the first: the base of the ratios)
    repeats: int = 1  #: batches of each worker count (median reported)

    def __post_init__(self) -> None:
        check_not_empty(self, "workers")


CLI = ProtocolCli("batch_scaling", Settings, __doc__, example="workers=1,2")


def make_list(work: Path) -> Path:
    """Generate the cases (if missing) and the list file naming them."""
    names = [ensure_sequence(case_sequence(c), work / "data" / c.name).name for c in CASES]
    listing = work / "data" / "cases.txt"
    listing.write_text("".join(f"{n}\n" for n in names))
    return listing


def run_batch(listing: Path, out: Path, workers: int) -> dict:
    """One batch of ``workers``; its wall time (s) and batch.json."""
    cmd = [sys.executable, "-m", "c3f_slam", "batch", str(listing), "--out", str(out), "--workers", str(workers),
           "--depth-source", "files", "--descriptors", "sift", "--overwrite", "--quiet"]
    t0 = time.perf_counter()
    r = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - t0
    if r.returncode not in (0, 2) or not (out / "batch.json").is_file():
        raise SystemExit(f"batch with {workers} worker(s) failed: {r.stderr.strip()[-500:]}")
    return {"wall_s": wall, "batch": json.loads((out / "batch.json").read_text())}


def _mean(values: list) -> float | None:
    values = [v for v in values if v is not None]
    return statistics.fmean(values) if values else None


def row(workers: int, runs: list[dict], base: float) -> dict:
    walls = [r["wall_s"] for r in runs]
    batch = runs[-1]["batch"]
    rows = batch["runs"]
    return {"workers": workers, "threads": batch["settings"]["threads"], "cores": batch["settings"]["cores"],
            "wall_s": statistics.median(walls), "walls_s": walls, "ratio": statistics.median(walls) / base,
            "ok": batch["counts"]["ok"], "failed": batch["counts"]["failed"],
            "run_s": sum(r["seconds"] or 0 for r in rows),
            "registered": _mean([r["registered_share"] for r in rows]), "ate_m": _mean([r["ate_rmse_m"] for r in rows])}


def table(rows: list[dict]) -> list[str]:
    lines = ["| workers | threads / cores each | wall s (median) | x of 1 worker | sum of run times s | ok / failed "
             "| registered % (mean) | ATE cm (mean) |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        ate = f"{100 * r['ate_m']:.3f}" if r["ate_m"] is not None else "-"
        reg = f"{100 * r['registered']:.1f}" if r["registered"] is not None else "-"
        lines.append(f"| {r['workers']} | {r['threads']} / {r['cores']} | {r['wall_s']:.1f} | {r['ratio']:.2f} | "
                     f"{r['run_s']:.1f} | {r['ok']} / {r['failed']} | {reg} | {ate} |")
    return lines


def main(argv: list[str] | None = None) -> None:
    ap = CLI.parser()
    ap.add_argument("--work", type=Path, default=WORK / "batch_scaling", help="folder for sequences and batches")
    ap.add_argument("--report", type=Path, default=RESULTS / "batch_scaling.md", help=REPORT_HELP)
    a, settings = CLI.parse(ap, argv)
    listing = make_list(a.work)
    runs: dict[int, list[dict]] = {w: [] for w in settings.workers}
    for _ in range(settings.repeats):
        for w in settings.workers:
            runs[w].append(run_batch(listing, a.work / f"out_{w}", w))
            print(f"{w} worker(s): {runs[w][-1]['wall_s']:.1f} s", flush=True)
    base = statistics.median(r["wall_s"] for r in runs[settings.workers[0]])
    rows = [row(w, runs[w], base) for w in settings.workers]
    lines = table(rows)
    print("\n".join(lines))
    body = [f"- {len(CASES)} coverage cases (seq1 seed 7, 300 frames, 128 px), true depth and SIFT, mesh and coverage "
            f"on; machine: {os.cpu_count()} cores; {settings.repeats} batch(es) per worker count, alternating.",
            "- wall: the whole `python -m c3f_slam batch` command (start, runs, evaluations, summary); sum of run "
            "times: the runs' own wall times (summary.json), which grow when runs share cores.", "", *lines]
    Report(__file__, "Batch reconstruction: wall time with 1 and more workers").publish(
        a.report, body, settings, data={"rows": rows}, options=a)
    print(f"wrote {a.report}")


if __name__ == "__main__":
    main()
