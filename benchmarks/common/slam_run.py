"""One ``python -m c3f_slam run`` of a benchmark: run once and kept (:func:`run_kept`), or run and
scored against the sequence's true poses (:func:`run_and_score`)."""

from __future__ import annotations

import json
import shlex
import subprocess
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path

from benchmarks.common import ROOT
from c3f_slam.evaluation.trajectory import evaluate_trajectory
from c3f_slam.io import Sequence as SequenceFolder
from c3f_slam.io import read_tum


def run_and_score(cmd: Sequence[str], out: Path, seq: Path, label: str, cwd: Path = ROOT,
                  env: Mapping[str, str] | None = None) -> tuple[dict, dict]:
    """Run ``cmd`` (a run command writing the run folder ``out``) in ``cwd``; its summary.json and
    :func:`c3f_slam.evaluation.trajectory.evaluate_trajectory` of its trajectory against ``seq``'s
    poses (lengths in metres). SystemExit naming ``label`` when the command fails."""
    proc = subprocess.run(list(cmd), cwd=cwd, env=dict(env) if env is not None else None, capture_output=True,
                          text=True)
    if proc.returncode != 0:
        raise SystemExit(f"{label}: {shlex.join(cmd)} failed: {proc.stderr.strip()[-400:]}")
    summary = json.loads((out / "summary.json").read_text())
    stamps, poses = read_tum(out / "trajectory.txt")
    gt = SequenceFolder(seq)
    return summary, evaluate_trajectory(stamps, poses, gt.timestamps, gt.poses, n_frames=len(gt))


def run_kept(source: Path, out: Path, args: Sequence[str] = (), cwd: Path = ROOT) -> dict:
    """``python -m c3f_slam run SOURCE ARGS --out OUT`` from ``cwd`` (another checkout: its code),
    unless ``out`` holds a summary.json already (a rerun of the protocol reuses the run); the
    summary. SystemExit naming ``out`` when the command fails."""
    if not (out / "summary.json").is_file():
        cmd = [sys.executable, "-m", "c3f_slam", "run", str(source), *args, "--out", str(out), "--quiet", "--overwrite"]
        proc = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)
        if proc.returncode != 0:
            raise SystemExit(f"{out}: {shlex.join(cmd)} failed: {proc.stderr.strip()[-400:]}")
    return json.loads((out / "summary.json").read_text())


__all__ = ["run_and_score", "run_kept"]
