"""SLAM runtime speed with NumPy's BLAS capped at one thread vs the library's default (outside CI).

The runtime's matrix products are small (a ~100x128 descriptor product per frame pair), where
a multi-threaded OpenBLAS can spend more time waking and synchronising its threads than it
saves, above all when other processes keep the cores busy. This runs the same sequence
with ``SlamConfig.blas_threads=1`` (the default) and ``None`` (the BLAS library's own
setting) alternately, ``--repeats`` times each, and reports the median per-stage times and
their ratio, plus a micro-benchmark of one descriptor matching. Run it on an idle machine and
again with ``--busy N`` (N busy-looping processes started beside it) to see both regimes.

    python -m benchmarks.studies.slam_blas_threads /work/slam_ate4500/seq1_s1 --max-frames 300 --busy 2
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_info, threadpool_limits

from benchmarks.common.report import Report
from c3f_slam.config import preset as slam_preset
from c3f_slam.matching import mutual_nearest_neighbours
from c3f_slam.pipeline import run_slam

STAGES = ("keypoints", "matching", "posegraph")
#: The two settings compared: name -> ``SlamConfig.blas_threads``.
SETTINGS = {"blas_threads=1": 1, "library default": None}


def _spin(stop) -> None:  # a busy core (another job on the machine)
    x = 0
    while not stop.is_set():
        x += 1


def micro(limit: int | None, repeats: int = 300) -> float:
    """Milliseconds per mutual-NN matching of two 120x128 SIFT-like descriptor sets."""
    rng = np.random.default_rng(0)
    a = rng.gamma(0.6, 30.0, (120, 128)).astype(np.float32)
    b = a[rng.permutation(120)] + rng.normal(0, 3, (120, 128)).astype(np.float32)
    ctx = threadpool_limits(limits=limit, user_api="blas") if limit else None
    try:
        t = time.perf_counter()
        for _ in range(repeats):
            mutual_nearest_neighbours(a, b, "l2", ratio=0.9)
        return 1e3 * (time.perf_counter() - t) / repeats
    finally:
        if ctx is not None:
            ctx.restore_original_limits()


def _arguments() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("sequence", type=Path, help="sequence folder with depth/ (RGB-D mode)")
    ap.add_argument("--max-frames", type=int, default=300)
    ap.add_argument("--repeats", type=int, default=2, help="runs per setting (alternating)")
    ap.add_argument("--min-correspondences", type=int, default=15)
    ap.add_argument("--busy", type=int, default=0, help="busy-looping processes to start beside the runs")
    ap.add_argument("--report", type=Path, default=None, help="Markdown report (default: print only)")
    return ap.parse_args()


def _alternating_runs(a: argparse.Namespace) -> tuple[dict[str, list[dict]], dict[str, list[float]]]:
    """Run the SLAM system ``a.repeats`` times per setting, alternating, with ``a.busy`` busy
    processes beside it; returns the run summaries and the micro-benchmark times (ms) per setting."""
    stop = mp.Event()
    spinners = [mp.Process(target=_spin, args=(stop,), daemon=True) for _ in range(a.busy)]
    for p in spinners:
        p.start()
    res: dict[str, list[dict]] = {k: [] for k in SETTINGS}
    micro_ms: dict[str, list[float]] = {k: [] for k in SETTINGS}
    try:
        with tempfile.TemporaryDirectory() as tmp:
            for r in range(a.repeats):
                for name, limit in SETTINGS.items():
                    cfg = slam_preset("colon", fusion={"enabled": False}, blas_threads=limit,
                                                   fragments={"min_correspondences": a.min_correspondences})
                    s = run_slam(a.sequence, Path(tmp) / f"{r}_{limit}", cfg.with_(frames={"max_frames": a.max_frames}),
                                 progress=False)
                    res[name].append(s)
                    micro_ms[name].append(micro(limit))
    finally:
        stop.set()
        for p in spinners:
            p.join()
    return res, micro_ms


def _report_lines(a: argparse.Namespace, res: dict[str, list[dict]], micro_ms: dict[str, list[float]]) -> list[str]:
    """Setup, identical-results check and the table of median per-stage times of both settings."""
    load = os.getloadavg()[0]
    blas = [f"{i['internal_api']} {i['version']} ({i['num_threads']} threads)" for i in threadpool_info()
            if i["user_api"] == "blas"]

    def med(name: str, stage: str) -> float:
        return statistics.median(s["timings"][stage]["ms_per_frame"] for s in res[name])

    def fps(name: str) -> float:
        return statistics.median(s["timings"]["total"]["frames_per_second"] for s in res[name])

    one, lib = SETTINGS
    lines = [
        (f"- {a.max_frames} frames of {a.sequence.name}, RGB-D, SIFT, full system, no mesh; {a.repeats} alternating "
         f"runs per setting, medians; {a.busy} busy-looping processes beside the runs; {os.cpu_count()} CPUs, "
         f"load average {load:.1f} at the end; "
         f"BLAS: {', '.join(blas) or 'none found'}."),
        (f"- Identical results: registered share {res[one][0]['registered_share']:.3f} vs "
         f"{res[lib][0]['registered_share']:.3f}, "
         f"keyframes {res[one][0].get('keyframes')} vs {res[lib][0].get('keyframes')}."),
        "",
        "| stage (ms/frame) | blas_threads=1 | library default | default / capped |",
        "|---|---|---|---|",
    ]
    for st in STAGES:
        x, y = med(one, st), med(lib, st)
        lines.append(f"| {st} | {x:.1f} | {y:.1f} | {y / x:.2f} |" if x > 0 else f"| {st} | {x:.1f} | {y:.1f} | - |")
    lines.append(f"| total frames/s | {fps(one):.1f} | {fps(lib):.1f} | {fps(one) / fps(lib):.2f} (speed-up) |")
    m1, m0 = statistics.median(micro_ms[one]), statistics.median(micro_ms[lib])
    lines.append(f"| one 120x120 descriptor matching (ms) | {m1:.3f} | {m0:.3f} | {m0 / m1:.2f} |")
    return lines


def main() -> None:
    a = _arguments()
    res, micro_ms = _alternating_runs(a)
    report = Report(__file__, "SLAM runtime: BLAS capped at one thread vs the library default")
    text = report.render(_report_lines(a, res, micro_ms))
    if a.report:
        report.write(a.report, text)
    print(text)


if __name__ == "__main__":
    main()
