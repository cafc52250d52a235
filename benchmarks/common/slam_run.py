"""One ``python -m c3f_slam run`` of a benchmark, scored against the sequence's true poses."""

from __future__ import annotations

import json
import shlex
import subprocess
from collections.abc import Mapping, Sequence
from pathlib import Path

from benchmarks.common import ROOT
from c3f_slam.io import Sequence as SequenceFolder
from c3f_slam.io import read_tum
from c3f_slam.trajectory_metrics import evaluate_trajectory


def run_and_score(cmd: Sequence[str], out: Path, seq: Path, label: str, cwd: Path = ROOT,
                  env: Mapping[str, str] | None = None) -> tuple[dict, dict]:
    """Run ``cmd`` (a run command writing the run folder ``out``) in ``cwd``; its summary.json and
    :func:`c3f_slam.trajectory_metrics.evaluate_trajectory` of its trajectory against ``seq``'s
    poses (lengths in metres). SystemExit naming ``label`` when the command fails."""
    proc = subprocess.run(list(cmd), cwd=cwd, env=dict(env) if env is not None else None, capture_output=True,
                          text=True)
    if proc.returncode != 0:
        raise SystemExit(f"{label}: {shlex.join(cmd)} failed: {proc.stderr.strip()[-400:]}")
    summary = json.loads((out / "summary.json").read_text())
    stamps, poses = read_tum(out / "trajectory.txt")
    gt = SequenceFolder(seq)
    return summary, evaluate_trajectory(stamps, poses, gt.timestamps, gt.poses, n_frames=len(gt))


__all__ = ["run_and_score"]
