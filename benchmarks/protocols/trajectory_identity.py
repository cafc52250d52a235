"""Do two source trees give the same trajectories, bit for bit, on the benchmark sequences?

For a change that must not change behaviour (a restructuring): generate the sequences (or
reuse them, by name, under ``--work``), run ``python -m c3f_slam run`` on each exactly as its
benchmark does (default settings, ground-truth depth, SIFT) once with the code of ``--before``
and once with that of ``--after`` (each a subprocess in that tree, ``PYTHONPATH`` set to it),
and compare the two ``trajectory.txt`` byte for byte (SHA-256 of each); where the run writes a
mesh (the coverage cases), ``mesh.ply``'s triangles too, in a canonical order
(:func:`mesh_fingerprint`: Open3D writes the same mesh in another order on every run).

Sets (setting ``sets``, several allowed):

- ``coverage``: the 7 cases of ``coverage_accuracy.md`` (300 frames, 128 px, mesh and coverage on);
- ``tracking128`` / ``tracking256``: the 12 bounded-event sequences of ``slam_tracking.md`` per
  frame size (3 presets x 2 seeds x 2 paces, 600 frames, no mesh);
- ``smoke``: the first coverage case only (a quick check of the set-up).

``--set names=A,B`` keeps only the named sequences of the chosen sets. A run is reused when its folder
holds a finished run of the same runtime code: the git tree of ``c3f_slam/`` in a tree without
uncommitted changes there (a tree with such changes always runs again); ``--after`` the same as
``--before`` thus runs the reference once, for later comparisons. Exit status 1 when a
trajectory differs or a run failed.

    python -m benchmarks.protocols.trajectory_identity --before /tmp/before --after . --work /tmp/identity \\
        --set sets=coverage,tracking128 --set jobs=1

Settings (``--print-config``: each with its default and meaning): :class:`Settings`; ``--before``
and ``--after`` (source trees) stay plain options.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import open3d as o3d

from benchmarks.common import RESULTS, ROOT, WORK
from benchmarks.common.protocol_cli import WORK_HELP, ProtocolCli, check_choices, check_not_empty
from benchmarks.common.report import Report
from benchmarks.common.simulate import SimSequence, ensure_sequence
from benchmarks.protocols import coverage_accuracy, slam_tracking

TRACKING_FRAMES = 600  #: frames per sequence of the runs recorded in slam_tracking.md
SIDES = ("before", "after")
SETS = ("smoke", "coverage", "tracking128", "tracking256")  #: the sets of sequences


@dataclass(frozen=True)
class Settings:
    """What trajectory_identity compares."""

    sets: tuple[str, ...] = ("coverage", "tracking128")  #: sets of sequences: smoke, coverage, tracking128, tracking256
    names: tuple[str, ...] = ()  #: only these sequences of the sets (none: all)
    jobs: int = 1  #: sequences at once

    def __post_init__(self) -> None:
        check_not_empty(self, "sets")
        check_choices("sets", self.sets, SETS)


CLI = ProtocolCli("trajectory_identity", Settings, __doc__, example="sets=smoke")


@dataclass(frozen=True)
class Target:
    """One sequence of a benchmark and how that benchmark runs the CLI on it."""

    name: str
    group: str
    spec: SimSequence
    command: Callable[[Path, Path], list[str]]  #: (sequence folder, run folder) -> the command line


def _tracking(size: int) -> list[Target]:
    out = []
    for pace in slam_tracking.PACES:
        for preset in slam_tracking.PRESETS:
            for seed in slam_tracking.SEEDS:
                name, spec = slam_tracking.tracking_sequence(preset, seed, pace, TRACKING_FRAMES, size)
                out.append(Target(name, f"tracking{size}", spec, slam_tracking.slam_command))
    return out


def _coverage() -> list[Target]:
    return [Target(f"coverage_{c.name}", "coverage", coverage_accuracy.case_sequence(c), coverage_accuracy.slam_command)
            for c in coverage_accuracy.CASES]


def targets(sets: list[str]) -> list[Target]:
    """The sequences of the named sets, in order, each once."""
    make = {"coverage": _coverage, "tracking128": lambda: _tracking(128), "tracking256": lambda: _tracking(256),
            "smoke": lambda: _coverage()[:1]}
    out: dict[str, Target] = {}
    for s in sets:
        for t in make[s]():
            out.setdefault(t.name, t)
    return list(out.values())


# ---------------------------------------------------------------------- trees and runs

def _git(tree: Path, *args: str) -> str:
    return subprocess.run(["git", *args], cwd=tree, capture_output=True, text=True, check=True).stdout.strip()


def code_key(tree: Path) -> str | None:
    """The git tree hash of ``tree``'s ``c3f_slam/`` (the runtime the CLI runs), or None when
    that folder has uncommitted changes (its runs are never reused)."""
    if _git(tree, "status", "--porcelain", "--", "c3f_slam"):
        return None
    return _git(tree, "rev-parse", "HEAD:c3f_slam")


def describe(tree: Path) -> str:
    """The tree's commit, with ``+changes`` when its runtime code has uncommitted changes."""
    return _git(tree, "rev-parse", "--short=10", "HEAD") + ("" if code_key(tree) else "+changes")


def sha256(path: Path) -> str | None:
    return hashlib.sha256(path.read_bytes()).hexdigest() if path.is_file() else None


def mesh_fingerprint(path: Path) -> str | None:
    """SHA-256 of a mesh's triangles (vertex positions and colours) in a canonical order: each
    triangle turned to start at its lexicographically smallest vertex (the winding kept), the
    triangles sorted. Open3D's hashed TSDF lists the same triangles in another order from one
    run to the next, so the file's bytes differ where the surface does not."""
    if not path.is_file():
        return None
    mesh = o3d.io.read_triangle_mesh(str(path))
    v, c, t = (np.asarray(a) for a in (mesh.vertices, mesh.vertex_colors, mesh.triangles))
    rank = np.empty(len(v), np.int64)
    rank[np.lexsort(v.T[::-1])] = np.arange(len(v))
    first = np.argmin(rank[t], axis=1)
    t = np.take_along_axis(t, (first[:, None] + np.arange(3)) % 3, axis=1)
    rows = np.concatenate([v[t].reshape(len(t), 9), c[t].reshape(len(t), -1)], axis=1)
    return hashlib.sha256(np.ascontiguousarray(rows[np.lexsort(rows.T[::-1])]).tobytes()).hexdigest()


def run_side(target: Target, seq: Path, tree: Path, key: str | None, out: Path) -> dict:
    """Run ``target`` with the code of ``tree`` into ``out`` (or reuse a finished run there of
    the same code ``key``); returns status, frames, registered share, trajectory SHA-256, seconds."""
    marker = out / "code_key.txt"
    summary_path = out / "summary.json"
    reused = key is not None and marker.is_file() and marker.read_text() == key and summary_path.is_file()
    seconds = None
    if not reused:
        marker.unlink(missing_ok=True)
        env = {**os.environ, "PYTHONPATH": str(tree)}
        t0 = time.perf_counter()
        proc = subprocess.run(target.command(seq, out), cwd=tree, env=env, capture_output=True, text=True)
        seconds = time.perf_counter() - t0
        if not summary_path.is_file():
            return {"status": f"failed: {proc.stderr.strip()[-300:]}", "seconds": seconds}
        if key is not None:
            marker.write_text(key)
    s = json.loads(summary_path.read_text())
    return {"status": s.get("status"), "frames": s.get("frames"), "registered_share": s.get("registered_share"),
            "sha256": sha256(out / "trajectory.txt"), "mesh_sha256": mesh_fingerprint(out / "mesh.ply"),
            "seconds": seconds, "reused": reused}


def run_folder(work: Path, target: Target, side: str, key: str | None) -> Path:
    """Where a side's run goes: by code (a tree without uncommitted runtime changes), so that
    a later comparison with the same code on either side reuses it; else by side."""
    return work / "runs" / target.name / (key[:12] if key else f"{side}-changes")


def compare(target: Target, trees: dict[str, Path], keys: dict[str, str | None], work: Path) -> dict:
    """Generate (or reuse) the sequence, run both sides, compare the trajectories."""
    seq = ensure_sequence(target.spec, work / target.name, echo=True)
    res = {side: run_side(target, seq, trees[side], keys[side], run_folder(work, target, side, keys[side]))
           for side in SIDES}
    b, a = res["before"], res["after"]
    identical = b.get("sha256") is not None and b.get("sha256") == a.get("sha256")
    mesh = None if b.get("mesh_sha256") is None else b["mesh_sha256"] == a.get("mesh_sha256")
    out = {"name": target.name, "group": target.group, "identical": identical, "mesh_identical": mesh, **res}
    print(f"{target.name}: {'identical' if identical else 'DIFFERENT'} "
          f"({b.get('status')} / {a.get('status')})", flush=True)
    return out


# ---------------------------------------------------------------------- report

def _share(r: dict) -> str:
    v = r.get("registered_share")
    return "-" if v is None else f"{100 * v:.1f}"


def _seconds(r: dict) -> str:
    return "reused" if r.get("reused") else "-" if r.get("seconds") is None else f"{r['seconds']:.0f}"


def _yes(v: bool | None) -> str:
    return "-" if v is None else "yes" if v else "**no**"


def table(results: list[dict]) -> list[str]:
    lines = ["| sequence | set | frames | registered % before / after | trajectory identical | SHA-256 before "
             "| SHA-256 after | mesh identical | seconds before / after |", "|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        b, a = r["before"], r["after"]
        lines.append(f"| {r['name']} | {r['group']} | {b.get('frames', '-')} | {_share(b)} / {_share(a)} |"
                     f" {_yes(r['identical'])} | `{(b.get('sha256') or '-')[:16]}` |"
                     f" `{(a.get('sha256') or '-')[:16]}` | {_yes(r['mesh_identical'])} |"
                     f" {_seconds(b)} / {_seconds(a)} |")
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = CLI.parser()
    ap.add_argument("--before", type=Path, required=True, help="source tree of the reference code")
    ap.add_argument("--after", type=Path, default=ROOT, help="source tree of the changed code (default: this one)")
    ap.add_argument("--work", type=Path, default=WORK / "trajectory_identity", help=WORK_HELP)
    ap.add_argument("--report", type=Path, default=RESULTS / "trajectory_identity.md",
                    help="Markdown report; the JSON goes beside it (.json)")
    a, settings = CLI.parse(ap, argv)
    chosen = [t for t in targets(settings.sets) if not settings.names or t.name in settings.names]
    trees = {"before": a.before.resolve(), "after": a.after.resolve()}
    keys = {side: code_key(tree) for side, tree in trees.items()}
    t0 = time.perf_counter()
    with ThreadPoolExecutor(max(1, settings.jobs)) as pool:
        results = list(pool.map(lambda t: compare(t, trees, keys, a.work), chosen))
    wall = time.perf_counter() - t0
    same = sum(r["identical"] for r in results)
    commits = {side: describe(tree) for side, tree in trees.items()}
    rep = Report(__file__, "Trajectories before and after, bit for bit")
    body = [f"- before: `{commits['before']}`, after: `{commits['after']}`; sets: {', '.join(settings.sets)}; "
            "each run as its benchmark runs it (ground-truth depth, SIFT, default settings).",
            f"- **{same} of {len(results)} trajectories identical** (SHA-256 of trajectory.txt; the first 16 hex "
            f"digits shown, all 64 in the JSON); wall time {wall / 60:.1f} min, {settings.jobs} at once; mesh "
            "identical: the same triangles (positions and colours, bit for bit, in a canonical order) where the "
            "benchmark writes a mesh (-: no mesh).", "",
            *table(results)]
    rep.publish(a.report, body, settings, options=a,
                data={"before": commits["before"], "after": commits["after"], "sets": settings.sets,
                      "wall_seconds": wall, "identical": same, "sequences": results})
    print(f"{same} of {len(results)} identical; wrote {a.report}")
    return 0 if same == len(results) else 1


if __name__ == "__main__":
    raise SystemExit(main())
