"""Frames per second of the colonoscopy simulator, generation including writing.

    python -m benchmarks.simulator_fps [--preset seq1] [--frames 300] [--size 256] [--seed 7]

Runs the real pipeline (``generate_sequence``: colon + path + texture, ray casting, shading,
PNG encoding of RGB and depth, mesh.ply, params.json, poses.txt) into a temporary folder and
reports: the set-up time, the steady rate (frames 10..N, writing included), the overall rate,
and a per-stage breakdown measured on extra frames (median per frame). Writes the numbers
and the exact command line to ``benchmarks/results/simulator_fps.md`` and prints them.
This is a measurement, not a test: the machine's load is recorded next to the numbers.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.common import RESULTS
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


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--preset", default="seq1")
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--out", default=str(RESULTS / "simulator_fps.md"))
    args = ap.parse_args(argv)

    import cv2
    import open3d

    from datamodules.synthetic.generate import generate_sequence
    from datamodules.synthetic.params import apply_overrides, get_preset

    params = apply_overrides(get_preset(args.preset), {"frames": args.frames, "size": args.size, "seed": args.seed})
    load_before = os.getloadavg()
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
    load_after = os.getloadavg()
    n = args.frames
    setup = stamps[0] - t0 if stamps else float("nan")
    skip = min(10, n - 1)
    steady = (n - 1 - skip) / (stamps[-1] - stamps[skip]) if n - 1 > skip else float("nan")
    cpu_ms = 1000 * (cpu[-1] - cpu[skip]) / (n - 1 - skip) if n - 1 > skip else float("nan")
    overall = n / total
    stages = _stage_breakdown(params, min(40, n))

    lines = [
        (f"Machine: {os.cpu_count()} CPU cores, {platform.processor() or platform.machine()}, "
         f"Python {platform.python_version()},"
         f" NumPy {np.__version__}, OpenCV {cv2.__version__}, Open3D {open3d.__version__}; no GPU."),
        (f"Load average (1 min) before / after: {load_before[0]:.2f} / {load_after[0]:.2f}"
         " (other jobs share these cores; rates scale with the free CPU)."),
        "",
        (f"Preset {params.preset}, {n} frames at {args.size}x{args.size}, seed {args.seed},"
         f" colon {params.colon.length} m, mesh of the full colon; output {size_mb:.1f} MB."),
        "",
        "| measure | value |",
        "|---|---|",
        f"| set-up (colon mesh, path planning, texture atlas) | {setup:.2f} s |",
        f"| steady rate, frames {skip}..{n - 1}, rendering + writing | **{steady:.1f} frames/s** |",
        f"| overall rate incl. set-up and mesh.ply | {overall:.1f} frames/s ({total:.1f} s total) |",
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
    report = Report(__file__, "Simulator throughput", argv)
    text = report.render(lines)
    report.write(Path(args.out), text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
