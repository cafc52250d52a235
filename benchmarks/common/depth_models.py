"""Depth models run over sequences with true depth, for the studies that compare them (outside CI)."""

from __future__ import annotations

import argparse
from collections.abc import Callable, Iterator
from collections.abc import Sequence as SequenceABC
from pathlib import Path

import numpy as np

from c3f_slam.io import Sequence
from c3f_slam.models import DepthModel
from c3f_slam.models.zoo import resolve


def add_depth_study_arguments(ap: argparse.ArgumentParser, every: int, report: Path, needs: str) -> None:
    """The arguments the depth studies share: sequence folders (which must have ``needs``), the
    depth models (repeatable), every n-th frame, onnxruntime threads and the report file."""
    ap.add_argument("sequences", type=Path, nargs="+", help=f"sequence folders with {needs}")
    ap.add_argument("--depth-model", action="append", required=True,
                    help="DepthNet ONNX export or zoo:NAME (repeatable: each gets its own rows)")
    ap.add_argument("--every", type=int, default=every, help="every n-th frame")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--report", type=Path, default=report)


def open_depth_model(name: str, threads: int) -> tuple[DepthModel, float]:
    """The DepthNet export ``name`` (a file or ``zoo:NAME``) and the factor to metres it records (1 without)."""
    model = DepthModel(resolve(name, "depth", "--depth-model"), threads, "--depth-model")
    return model, model.metric_scale or 1.0


def depth_runs(names: SequenceABC[str], paths: SequenceABC[Path], threads: int, needs_poses: bool = False
               ) -> Iterator[tuple[str, Path, Sequence, Callable[[int], np.ndarray]]]:
    """For each depth model of ``names`` and each sequence folder of ``paths`` (which must have
    depth/, and poses.txt with ``needs_poses``): (name, path, sequence, predict), ``predict(i)``
    giving frame i's predicted depth in metres (the recorded scale applied)."""
    for name in names:
        model, scale = open_depth_model(name, threads)
        for path in paths:
            seq = Sequence(path)
            if not seq.has_depth or (needs_poses and not seq.has_poses):
                raise SystemExit(f"{path}: needs depth/" + (" and poses.txt" if needs_poses else ""))

            def predict(i: int, seq: Sequence = seq, model: DepthModel = model, scale: float = scale) -> np.ndarray:
                return model.predict(seq.read_rgb(i), seq.camera) * scale

            yield name, path, seq, predict
