"""Frames per second of the colonoscopy simulator, generation including writing.

    python -m benchmarks.protocols.simulator_fps [--set preset=seq1] [--set frames=300] [--set size=256] [--set seed=7]

Runs the real pipeline (``generate_sequence``: colon + path + texture, ray casting, shading,
PNG encoding of RGB and depth, mesh.ply, params.json, poses.txt) into a temporary folder and
reports: the set-up time, the steady rate (frames 10..N, writing included), the overall rate,
and a per-stage breakdown measured on extra frames (median per frame). Writes the numbers
and the exact command line to ``benchmarks/results/simulator_fps.md`` (and ``.json``) and prints them.
This is a measurement, not a test: the machine's load is recorded next to the numbers.
Settings (``--print-config``: each with its default and meaning): :class:`Settings`.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from benchmarks.common import RESULTS
from benchmarks.common.protocol_cli import REPORT_HELP, ProtocolCli
from benchmarks.common.report import Report


def _stage_breakdown(params, frames: int) -> dict[str, float]:
    """Median milliseconds per frame of each stage, on ``frames`` frames of the same scene."""
    from c3f_slam.io import SequenceWriter
    from datamodules.synthetic.noise import FRAME, stream
    from datamodules.synthetic.scene import build_scene

    scene = build_scene(params)
    r = scene.renderer
    times: dict[str, list[float]] = {"ray cast": [], "shade + texture": [], "sensor (exposure, bloom, grain)": [],
                                     "PNG write (rgb + depth)": []}
    with tempfile.TemporaryDirectory() as tmp:
        writer = SequenceWriter(tmp, scene.camera)
        for i in range(min(frames, len(scene.path.poses))):
            T = scene.path.poses[i]
            t0 = time.perf_counter()
            hits = r.trace(T)
            t1 = time.perf_counter()
            rad, lum = r.shade(hits, T)
            t2 = time.perf_counter()
            rgb = r.expose(rad, lum, stream(params.seed, FRAME, i))
            t3 = time.perf_counter()
            writer.write_frame(i, rgb, hits.depth)
            t4 = time.perf_counter()
            for k, dt in zip(times, (t1 - t0, t2 - t1, t3 - t2, t4 - t3)):
                times[k].append(dt * 1000)
    return {k: float(np.median(v)) for k, v in times.items()}


@dataclass
class _Run:
    """Wall-clock stamps of one timed ``generate_sequence`` run."""

    start: float  # perf_counter() before the run, s
    stamps: list[float]  # perf_counter() as each frame was done, s
    cpu: list[float]  # process CPU seconds (all threads) as each frame was done
    total: float  # duration of the whole run, s
    size_mb: float  # size of everything written, MB


@dataclass
class _Rates:
    """Throughput derived from a :class:`_Run` of ``n`` frames."""

    setup: float  # s until the first frame was done
    skip: int  # frames left out of the steady part
    steady: float  # frames/s over frames skip..n-1
    cpu_ms: float  # CPU ms per frame over the steady part
    overall: float  # frames/s including set-up and mesh.ply


@dataclass(frozen=True)
class Settings:
    """What simulator_fps measures."""

    preset: str = "seq1"  #: the simulator's preset (default, seq1..seq8, tiny)
    frames: int = 300  #: frames generated
    size: int = 256  #: frame size (square), pixels
    seed: int = 7  #: simulator seed


CLI = ProtocolCli("simulator_fps", Settings, __doc__, example="frames=100")


def _arguments(argv: list[str] | None) -> argparse.Namespace:
    """The plain options, each setting as an attribute too (``args.frames``), and ``args.settings`` (the tree)."""
    ap = CLI.parser()
    ap.add_argument("--report", "--out", type=Path, default=RESULTS / "simulator_fps.md",
                    help=REPORT_HELP + " (--out: its former name)")
    return CLI.flat(*CLI.parse(ap, argv))


def _timed_generation(params) -> _Run:
    """Generate the sequence of ``params`` into a temporary folder, stamping every frame."""
    from datamodules.synthetic.generate import generate_sequence

    stamps: list[float] = []
    cpu: list[float] = []

    def tick(i: int) -> None:
        stamps.append(time.perf_counter())
        cpu.append(time.process_time())  # CPU seconds of all threads of this process

    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        generate_sequence(params, Path(tmp) / "seq", progress=False, on_frame=tick)
        total = time.perf_counter() - t0
        size_mb = sum(f.stat().st_size for f in (Path(tmp) / "seq").rglob("*") if f.is_file()) / 1e6
    return _Run(start=t0, stamps=stamps, cpu=cpu, total=total, size_mb=size_mb)


def _rates(run: _Run, n: int) -> _Rates:
    """Set-up time and rates of ``run``; the steady part leaves out the first (up to) 10 frames."""
    stamps, cpu = run.stamps, run.cpu
    setup = stamps[0] - run.start if stamps else float("nan")
    skip = min(10, n - 1)
    steady = (n - 1 - skip) / (stamps[-1] - stamps[skip]) if n - 1 > skip else float("nan")
    cpu_ms = 1000 * (cpu[-1] - cpu[skip]) / (n - 1 - skip) if n - 1 > skip else float("nan")
    return _Rates(setup=setup, skip=skip, steady=steady, cpu_ms=cpu_ms, overall=n / run.total)


def _report_lines(args: argparse.Namespace, params, run: _Run, rates: _Rates, stages: dict[str, float],
                  loads: tuple[float, float]) -> list[str]:
    """The report's body; ``loads``: 1-minute load average before and after the run."""
    import cv2
    import open3d

    n, skip, cpu_ms = args.frames, rates.skip, rates.cpu_ms
    lines = [
        (f"Machine: {os.cpu_count()} CPU cores, {platform.processor() or platform.machine()}, "
         f"Python {platform.python_version()},"
         f" NumPy {np.__version__}, OpenCV {cv2.__version__}, Open3D {open3d.__version__}; no GPU."),
        (f"Load average (1 min) before / after: {loads[0]:.2f} / {loads[1]:.2f}"
         " (other jobs share these cores; rates scale with the free CPU)."),
        "",
        (f"Preset {params.preset}, {n} frames at {args.size}x{args.size}, seed {args.seed},"
         f" colon {params.colon.length} m, mesh of the full colon; output {run.size_mb:.1f} MB."),
        "",
        "| measure | value |",
        "|---|---|",
        f"| set-up (colon mesh, path planning, texture atlas) | {rates.setup:.2f} s |",
        f"| steady rate, frames {skip}..{n - 1}, rendering + writing | **{rates.steady:.1f} frames/s** |",
        f"| overall rate incl. set-up and mesh.ply | {rates.overall:.1f} frames/s ({run.total:.1f} s total) |",
        f"| CPU time per frame (all threads), steady part | {cpu_ms:.0f} ms |",
        f"| bound with both cores free: 2 cores / CPU time per frame | {2000 / cpu_ms:.0f} frames/s |",
        "",
        "Per-stage median per frame (single-threaded stages except ray casting, which uses all cores;",
        "in `generate_sequence` the PNG writing runs in a background thread, overlapping the next frame):",
        "",
        "| stage | ms/frame |",
        "|---|---|",
    ]
    lines += [f"| {k} | {v:.1f} |" for k, v in stages.items()]
    lines += [f"| sum | {sum(stages.values()):.1f} |"]
    return lines


def main(argv: list[str] | None = None) -> int:
    args = _arguments(argv)

    from c3f_core.settings import tree_from_mapping
    from datamodules.synthetic.params import SIM_SETTINGS

    params = tree_from_mapping(SIM_SETTINGS.tree(args.preset), {
        "seed": args.seed, "path": {"frames": args.frames}, "camera": {"width": args.size, "height": args.size}})
    load_before = os.getloadavg()
    run = _timed_generation(params)
    load_after = os.getloadavg()
    rates = _rates(run, args.frames)
    stages = _stage_breakdown(params, min(40, args.frames))
    report = Report(__file__, "Simulator throughput", argv)
    lines = _report_lines(args, params, run, rates, stages, (load_before[0], load_after[0]))
    data = {**asdict(rates), "total_s": run.total, "size_mb": run.size_mb, "stage_ms": stages,
            "load_before_after": [load_before[0], load_after[0]]}  # the table's numbers without their units
    print(report.publish(args.report, lines, args.settings, data=data, options={"report": args.report}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
