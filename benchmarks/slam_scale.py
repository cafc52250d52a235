"""Scaling of the SLAM runtime over a long RGB-D stream (outside CI).

A long sequence is made without rendering thousands of frames: a short simulator sequence
is played forward and backward repeatedly through symbolic links (ping-pong), so the camera
keeps revisiting the same colon stretch (every new keyframe has real matches among the
earlier ones, the worst case for the all-keyframe matching). Every ``--every`` frames the
script records the resident memory (VmRSS), the time per frame of the last interval and
the number of keyframes; the table goes to benchmarks/results/slam_scale.md.

    python benchmarks/slam_scale.py --frames 20000 --base-frames 120 --size 64
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from c3f_slam.io import Sequence, write_tum  # noqa: E402
from c3f_slam.pipeline import SlamConfig, run_slam  # noqa: E402
from c3f_slam.pipeline.slam import FragmentSlam  # noqa: E402
from datamodules.synthetic.fixture import make_tiny_sequence  # noqa: E402


def rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def ping_pong(src: Path, dst: Path, n: int) -> Path:
    """A sequence of ``n`` frames linking to ``src``'s frames 0..N-1, N-2..1, 0.. (ping-pong)."""
    seq = Sequence(src)
    m = len(seq)
    cycle = list(range(m)) + list(range(m - 2, 0, -1))
    order = [cycle[k % len(cycle)] for k in range(n)]
    (dst / "rgb").mkdir(parents=True, exist_ok=True)
    (dst / "depth").mkdir(exist_ok=True)
    for k, i in enumerate(order):
        for sub, paths in (("rgb", seq.rgb_paths), ("depth", seq.depth_paths)):
            link = dst / sub / f"{k:06d}.png"
            if not link.exists():
                os.symlink(paths[i].resolve(), link)
    write_tum(dst / "poses.txt", np.arange(n) / 30.0, seq.poses[order])
    (dst / "camera.json").write_text((src / "camera.json").read_text())
    return dst


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=20000)
    ap.add_argument("--base-frames", type=int, default=120)
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--every", type=int, default=500)
    ap.add_argument("--min-correspondences", type=int, default=15)
    ap.add_argument("--mesh", action="store_true", help="fuse too (the fused volume grows with the surface)")
    ap.add_argument("--out", type=Path, default=Path("/tmp/slam_scale"))
    ap.add_argument("--report", type=Path, default=ROOT / "benchmarks" / "results" / "slam_scale.md")
    args = ap.parse_args()

    base = args.out / f"base_{args.base_frames}_{args.size}"
    if not (base / "camera.json").is_file():
        make_tiny_sequence(base, frames=args.base_frames, size=args.size, seed=5)
    long_seq = ping_pong(base, args.out / f"long_{args.frames}", args.frames)

    samples: list[tuple[int, float, float, int, float]] = []

    class Probe(FragmentSlam):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            self._t = time.perf_counter()
            self._n = 0

        def _tick(self) -> None:
            self._n += 1
            if self._n % args.every == 0:
                now = time.perf_counter()
                kb = sum(k.nbytes for k in self.keyframes) / 2**20
                samples.append((self._n, 1000 * (now - self._t) / args.every, rss_mb(), len(self.keyframes), kb))
                self._t = now
                print(samples[-1], flush=True)

        def add(self, feat, depth):
            out = super().add(feat, depth)
            self._tick()
            return out

        def skip(self, index, stamp):
            super().skip(index, stamp)
            self._tick()

    cfg = SlamConfig.preset_config("colon", min_consecutive_correspondences=args.min_correspondences,
                                   fuse=args.mesh)
    t = time.perf_counter()
    error = ""
    try:
        s = run_slam(long_seq, args.out / "run", cfg, progress=False, slam_factory=Probe)
    except Exception as exc:
        error, s = str(exc), {}
    wall = time.perf_counter() - t
    rows = [f"| {n} | {ms:.1f} | {mb:.0f} | {kf} | {kmb:.2f} |" for n, ms, mb, kf, kmb in samples]
    cmd = (f"python benchmarks/slam_scale.py --frames {args.frames} --base-frames {args.base_frames} "
           f"--size {args.size} --every {args.every} --min-correspondences {args.min_correspondences}"
           + (" --mesh" if args.mesh else ""))
    text = "\n".join([
        "# SLAM scaling over a long RGB-D stream", "", f"Command: `{cmd}`", "",
        f"- Stream: a {args.base_frames}-frame simulator sequence ({args.size} px, 15 cm colon) played forward "
        f"and backward (ping-pong, symbolic links) to {args.frames} frames; ground-truth depth, SIFT.",
        f"- Wall time {wall:.0f} s; registered share {s.get('registered_share', float('nan')):.3f}; "
        f"keyframes {s.get('keyframes')}; fragments {s.get('fragments')}; loop edges {s.get('loop_edges')}; "
        f"pruned {s.get('pruned_edges')}; mesh {'on' if args.mesh else 'off'}." + (f" Error: {error}" if error else ""),
        "- Per interval: ms per frame over the last interval, resident memory of the process, keyframes so far, "
        "memory of the stored keyframe features.", "",
        "| frames | ms/frame (interval) | RSS MB | keyframes | keyframe data MB |", "|---|---|---|---|---|",
        *rows, ""])
    args.report.parent.mkdir(parents=True, exist_ok=True)
    args.report.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
