"""Scaling of the SLAM runtime over a long RGB-D stream (outside CI).

A long sequence is made without rendering thousands of frames: a short simulator sequence
is played forward and backward repeatedly through symbolic links (ping-pong), so the camera
keeps revisiting the same colon stretch (every new keyframe has real matches among the
earlier ones, the worst case for the all-keyframe matching). Every ``every`` frames the
script records the resident memory (VmRSS), the time per frame of the last interval (total
and per stage), the number of keyframes, the keyframe pairs matched per new keyframe and the
global optimisations; the table goes to benchmarks/results/slam_scale.md (and .json).
``--set paper_rules=true`` restores the literal rules (match all keyframes, optimise the whole component after every
loop) for comparison on short runs.

    python -m benchmarks.protocols.slam_scale --set frames=20000 --set base_frames=120 --set size=64 \\
        --set every=1000

Inputs: the base sequence is the simulator's seeded fixture, made under ``--work`` (default
``runs/bench/slam_scale``); no model. Settings (``--print-config``: each with its default and
meaning): :class:`Settings`.
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np

from benchmarks.common import RESULTS, WORK
from benchmarks.common.protocol_cli import REPORT_HELP, ProtocolCli
from benchmarks.common.report import Report
from c3f_slam.config import preset as slam_preset
from c3f_slam.io import Sequence, write_tum
from c3f_slam.pipeline import PAPER_RULES, SlamConfig, run_slam
from c3f_slam.pipeline.run_evaluation import evaluate_run
from c3f_slam.pipeline.slam import FragmentSlam
from datamodules.synthetic.fixture import make_tiny_sequence


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


STAGES = ("io", "depth", "keypoints", "matching", "posegraph", "fusion")


class Probe(FragmentSlam):
    """The full system, sampling its time, memory and counters every ``every`` frames into
    ``samples`` and timing the final optimisation into ``final`` (see :func:`probe_class`)."""

    every: ClassVar[int] = 500
    samples: ClassVar[list[dict]] = []
    final: ClassVar[dict] = {}

    def __init__(self, *a, **k):
        super().__init__(*a, **k)
        self._t = time.perf_counter()
        self._cpu = time.process_time()
        self._n = 0
        self._stages = dict.fromkeys(STAGES, 0.0)
        self._frag = self._pairs = self._opts = self._win = 0

    def _tick(self) -> None:
        self._n += 1
        if self._n % self.every == 0:
            now, cpu = time.perf_counter(), time.process_time()
            sec = {st: self.t.seconds.get(st, 0.0) for st in STAGES}
            new_frag = self.map.counts.fragments - self._frag
            self.samples.append({
                "frames": self._n, "ms": 1000 * (now - self._t) / self.every,
                "cpu_ms": 1000 * (cpu - self._cpu) / self.every,
                "rss": rss_mb(), "kf": len(self.map.keyframes),
                "kf_mb": self.map.keyframe_memory_bytes() / 2**20, "kf_disk_mb": self.map.keyframes.disk_bytes / 2**20,
                "edges": self.map.graph.n_edges, "edge_mb": self.map.graph.edge_nbytes() / 2**20,
                "stage_ms": {st: 1000 * (sec[st] - self._stages[st]) / self.every for st in STAGES},
                "pairs": (self.placer.counts.candidates_matched - self._pairs) / max(new_frag, 1),
                "opts": self.map.schedule.counts.optimizations - self._opts,
                "win": self.map.schedule.counts.windowed - self._win,
            })
            self._t, self._cpu, self._stages, self._frag = now, cpu, sec, self.map.counts.fragments
            opt = self.map.schedule.counts
            self._pairs, self._opts, self._win = self.placer.counts.candidates_matched, opt.optimizations, opt.windowed
            r = self.samples[-1]
            print(f"{r['frames']} frames: {r['ms']:.1f} ms/frame (CPU {r['cpu_ms']:.1f}), "
                  f"RSS {r['rss']:.0f} MB, {r['kf']} keyframes, "
                  f"{r['pairs']:.1f} pairs/fragment, {r['opts']} opt ({r['win']} windowed), "
                  + " ".join(f"{k} {v:.1f}" for k, v in r["stage_ms"].items()), flush=True)

    def add(self, frame):
        out = super().add(frame)
        self._tick()
        return out

    def skip(self, index, stamp):
        super().skip(index, stamp)
        self._tick()

    def finish(self):
        t0 = time.perf_counter()
        n0 = self.map.schedule.counts.optimizations
        super().finish()
        self.final.update(seconds=time.perf_counter() - t0, optimizations=self.map.schedule.counts.optimizations - n0)


def probe_class(every: int) -> type[Probe]:
    """A :class:`Probe` subclass of its own (fresh ``samples`` and ``final``) sampling every ``every`` frames."""
    return type("Probe", (Probe,), {"every": every, "samples": [], "final": {}})


@dataclass(frozen=True)
class Settings:
    """What slam_scale measures."""

    frames: int = 20000  #: frames of the long stream
    base_frames: int = 120  #: frames of the simulator sequence played forward and backward
    size: int = 64  #: square frame size, pixels
    every: int = 500  #: frames between two samples of the table
    min_correspondences: int | None = None  #: fragment threshold (none: the preset's, derived from the frame size)
    mesh: bool = False  #: fuse too (the fused volume grows with the surface)
    #: match all keyframes, keep all their loop edges and optimise whole components after every loop (the
    #: literal rules)
    paper_rules: bool = False
    #: keep the stored keyframes' features in RAM (SlamConfig.keyframes.cache=False) instead of the run's
    #: keyframe cache file
    keyframes_in_ram: bool = False
    #: SlamConfig.keyframes.reuse (revisits hang off mapped keyframes); none: the config's
    reuse_keyframes: bool | None = None


CLI = ProtocolCli("slam_scale", Settings, __doc__, example="frames=2000")


def parse_args(argv: list[str] | None = None) -> tuple[argparse.Namespace, Settings]:
    """The plain options (work folder, report) and the settings of ``argv``."""
    ap = CLI.parser()
    ap.add_argument("--work", "--out", type=Path, default=WORK / "slam_scale",
                    help="folder for the sequences and the run (--out: its former name)")
    ap.add_argument("--report", type=Path, default=RESULTS / "slam_scale.md", help=REPORT_HELP)
    return CLI.parse(ap, argv)


def slam_config(settings: Settings) -> SlamConfig:
    """The colon preset with the run's options."""
    over: dict = {part: dict(fields) for part, fields in PAPER_RULES.items()} if settings.paper_rules else {}
    over.setdefault("keyframes", {})
    if settings.keyframes_in_ram:
        over["keyframes"]["cache"] = False
    if settings.reuse_keyframes is not None:
        over["keyframes"]["reuse"] = settings.reuse_keyframes
    if settings.min_correspondences is not None:
        over["fragments"] = {**over.get("fragments", {}), "min_correspondences": settings.min_correspondences}
    return slam_preset("colon", fusion={"enabled": settings.mesh}, **over)


def report_body(settings: Settings, cfg: SlamConfig, probe: type[Probe], *, wall: float, s: dict, ev: dict,
                error: str) -> list[str]:
    """Stream, settings and totals, then one table row per sample (times in ms, memory in MB)."""
    final = probe.final
    rows = [
        f"| {r['frames']} | {r['ms']:.1f} | {r['cpu_ms']:.1f} | "
        + " | ".join(f"{r['stage_ms'][k]:.1f}" for k in ("keypoints", "matching", "posegraph"))
        + f" | {r['rss']:.0f} | {r['kf']} | {r['kf_mb']:.2f} | {r['kf_disk_mb']:.2f} | {r['edges']} | "
        f"{r['edge_mb']:.1f} | {r['pairs']:.1f} | {r['opts']} ({r['win']}) |"
        for r in probe.samples]

    return [
        (f"- Stream: a {settings.base_frames}-frame simulator sequence ({settings.size} px, 15 cm colon) played "
         f"forward and backward (ping-pong, symbolic links) to {settings.frames} frames; ground-truth depth, SIFT; "
         "2 CPU cores shared with other jobs."),
        "- Settings: " + "; ".join(f"{part}: {asdict(getattr(cfg, part))}"
                                   for part in ("candidates", "keyframes", "optimization"))
        + ", fragments.min_correspondences="
        + f"{cfg.for_frame_size(settings.size, settings.size).fragments.min_correspondences}"
        + (" (given)" if settings.min_correspondences is not None else " (derived from the frame size)") + ".",
        f"- Wall time {wall:.0f} s (final optimisation {final.get('seconds', float('nan')):.1f} s, "
        f"{final.get('optimizations', 0)} runs); registered share {s.get('registered_share', float('nan')):.3f}; "
        f"ATE (SE(3), registered frames) {100 * ev.get('ate_se3', {}).get('rmse_m', float('nan')):.2f} cm, "
        f"(Sim(3)) {100 * ev.get('ate_sim3', {}).get('rmse_m', float('nan')):.2f} cm"
        + (f" [evaluation: {ev['error']}]" if "error" in ev else "") + "; "
        f"keyframes {s.get('keyframes')}; fragments {s.get('fragments')} "
        f"(attached to earlier keyframes: {s.get('attached_fragments', 0)}); loop edges {s.get('loop_edges')}; "
        f"pruned {s.get('pruned_edges')}; global optimisations {s.get('global_optimizations')} "
        f"({s.get('windowed_optimizations')} windowed, at most {s.get('max_optimized_nodes')} nodes); "
        f"keyframe pairs matched per new fragment {s.get('keyframe_candidates_per_fragment', float('nan')):.1f}; "
        f"keyframe cache on disk {s.get('keyframe_disk_bytes', 0) / 2**20:.1f} MB at the end (removed after the run); "
        f"accepted keyframe matches by source {s.get('keyframe_matches_by_source')} "
        f"(of them discarded by the loop-edge cap: {s.get('keyframe_matches_capped')}); "
        f"mesh {'on' if settings.mesh else 'off'}." + (f" Error: {error}" if error else ""),
        ("- Per interval of the last frames: wall-clock ms per frame (total, then the process's CPU time, "
         "which other jobs on the shared cores disturb less, then the wall-clock keypoint, matching and "
         "pose-graph stages), resident memory of the process, keyframes so far, "
         "RAM held by the stored keyframe features "
         "(incl. global descriptors; with the keyframe cache: per-keyframe records and an LRU of 64 keyframes), "
         "their bytes in the keyframe cache file (OUT/.keyframe_cache), "
         "global graph edges and the memory of their arrays (at capacity), "
         "keyframe pairs matched per new fragment (each new fragment's first frame is matched against the "
         "keyframe candidates, then becomes a keyframe or, with reuse_keyframes, hangs off one), global "
         "optimisations (of them windowed)."), "",
        ("| frames | ms/frame | CPU ms/frame | keypoints | matching | posegraph | RSS MB | keyframes "
         "| keyframe RAM MB | keyframe disk MB | edges | edge MB | pairs/fragment | optimisations |"),
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
        *rows
    ]


def main(argv: list[str] | None = None) -> None:
    args, settings = parse_args(argv)
    base = args.work / f"base_{settings.base_frames}_{settings.size}"
    if not (base / "camera.json").is_file():
        make_tiny_sequence(base, frames=settings.base_frames, size=settings.size, seed=5)
    long_seq = ping_pong(base, args.work / f"long_{settings.frames}_{settings.size}", settings.frames)
    cfg = slam_config(settings)
    probe = probe_class(settings.every)
    t = time.perf_counter()
    error = ""
    try:
        s = run_slam(long_seq, args.work / "run", cfg, progress=False, slam_factory=probe, overwrite=True)
    except Exception as exc:  # noqa: BLE001 -- a failed run is a result: report it
        error, s = str(exc), {}
    wall = time.perf_counter() - t
    ev = {}
    if s:
        try:
            ev = evaluate_run(args.work / "run", long_seq)
        except Exception as exc:  # noqa: BLE001 -- report, do not lose the table
            ev = {"error": str(exc)}
    report = Report(__file__, "SLAM scaling over a long RGB-D stream", argv)
    print(report.publish(args.report, report_body(settings, cfg, probe, wall=wall, s=s, ev=ev, error=error), settings,
                         options=args))


if __name__ == "__main__":
    main()
