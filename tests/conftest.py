"""Shared pytest fixtures: tiny sequences made on the fly (nothing is downloaded)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from tests.scenes import plane_sequence

os.environ.setdefault("PYTHONHASHSEED", "0")

try:  # one intra-op thread per test process: with pytest -n 2 on 2 cores, more threads thrash
    import torch

    torch.set_num_threads(1)
except ImportError:  # the runtime-only install has no torch
    pass


@pytest.fixture(scope="session")
def plane_dataset(tmp_path_factory) -> Path:
    """A data folder with three short analytic plane sequences (exact depth and poses)."""
    root = tmp_path_factory.mktemp("plane_data")
    for k in range(3):
        plane_sequence(root / f"plane{k}", frames=6, size=48, seed=k)
    return root


@pytest.fixture(scope="session")
def tiny_sequence(tmp_path_factory) -> Path:
    """A tiny simulated colon sequence (8 frames, 64x64, depth, poses, mesh): the simulator's fixture."""
    from datamodules.synthetic.fixture import make_tiny_sequence

    return make_tiny_sequence(tmp_path_factory.mktemp("sim") / "tiny", frames=8, size=64, seed=0)


@pytest.fixture(scope="session")
def sim_dataset(tmp_path_factory) -> Path:
    """A data folder of three tiny simulated sequences with different seeds (for split tests)."""
    from datamodules.synthetic.fixture import make_tiny_sequence

    root = tmp_path_factory.mktemp("sim_data")
    for k in range(3):
        make_tiny_sequence(root / f"sim{k}", frames=6, size=48, seed=k)
    return root


@pytest.fixture(scope="session")
def published(tmp_path_factory):
    """``published(layout) -> (sim_root, layout_root)``: a tiny simulated sequence written in
    the project's layout and, beside it, in a published data set's layout (made once per
    session). The camera matches what each data set's loader assumes by default."""
    from tests.published_data import make_published

    made: dict[str, tuple[Path, Path]] = {}

    def get(layout: str) -> tuple[Path, Path]:
        if layout not in made:
            made[layout] = make_published(tmp_path_factory.mktemp(f"pub_{layout}") / "sim", layout)
        return made[layout]

    return get
