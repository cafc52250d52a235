"""Shared pytest fixtures: tiny sequences made on the fly (nothing is downloaded); the ``torch``
mark, given to every test of a file that needs the training stack.

Marks (``pyproject.toml``): ``slow`` (left out by default), ``e2e`` (end to end: the project's
commands across packages; left out of ``make check``), ``torch`` (needs ``pip install -e
".[train]"``). The ``torch`` mark is not written by hand: a test file that imports the training
stack, or starts ``python -m c3f_models`` / ``c3f_demo``, gets it (:func:`needs_training_stack`).
Without torch those files are not even collected, so ``pytest`` on the runtime-only install
(``pip install -e ".[test]"``) runs the runtime's tests alone.
"""

from __future__ import annotations

import ast
import importlib.util
import os
from functools import cache
from pathlib import Path

import pytest

from tests.scenes import plane_sequence

os.environ.setdefault("PYTHONHASHSEED", "0")

HAVE_TORCH = importlib.util.find_spec("torch") is not None
if HAVE_TORCH:  # one intra-op thread per test process: with pytest -n 2 on 2 cores, more threads thrash
    import torch

    torch.set_num_threads(1)
if importlib.util.find_spec("lightning") is not None:
    # Lightning's console log handler takes sys.stderr when lightning is first imported. c3f_models.cli
    # imports it only when a Lightning subcommand runs, i.e. inside a test, whose captured stderr would
    # then get every later test's "Seed set to 42" lines; imported here, it writes to the real stderr.
    import lightning  # noqa: F401

#: top-level modules of the training stack and the packages built on it
TRAINING_STACK = frozenset({"torch", "torchvision", "lightning", "kornia", "jsonargparse", "safetensors", "tensorboard",
                            "onnxscript", "c3f_models", "export", "c3f_demo", "benchmarks"})
#: the parts of datamodules that import without torch (tests/test_import_boundary.py proves it)
TORCH_FREE_DATAMODULES = ("datamodules.synthetic", "datamodules.formats", "datamodules.convert", "datamodules.config",
                          "datamodules.__main__", "datamodules.phantom", "datamodules.ingest")
#: commands whose start in a subprocess (``[sys.executable, "-m", NAME, ...]``) needs the stack
TRAINING_COMMANDS = frozenset({"c3f_models", "c3f_demo"})


def _module_needs_torch(name: str) -> bool:
    top = name.split(".")[0]
    if top == "datamodules":
        return name != "datamodules" and not name.startswith(TORCH_FREE_DATAMODULES)
    return top in TRAINING_STACK


@cache
def needs_training_stack(path: Path) -> bool:
    """Whether the test file imports the training stack anywhere (top level or in a test) or
    starts one of :data:`TRAINING_COMMANDS` (a list or tuple with ``"-m", NAME``)."""
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import) and any(_module_needs_torch(a.name) for a in node.names):
            return True
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module, *(f"{node.module}.{a.name}" for a in node.names if node.module == "datamodules")]
            if any(_module_needs_torch(n) for n in names):
                return True
        if isinstance(node, (ast.List, ast.Tuple)):  # [..., "-m", "c3f_models", ...]
            words = [e.value if isinstance(e, ast.Constant) else None for e in node.elts]
            if any(a == "-m" and b in TRAINING_COMMANDS for a, b in zip(words, words[1:])):
                return True
    return False


def pytest_ignore_collect(collection_path: Path, config) -> bool | None:
    """Without torch, the files that need it are not collected (their imports would fail)."""
    if not HAVE_TORCH and collection_path.suffix == ".py" and collection_path.name.startswith("test_"):
        return True if needs_training_stack(collection_path) else None
    return None


def pytest_collection_modifyitems(config, items) -> None:
    for item in items:
        if needs_training_stack(Path(str(item.fspath))):
            item.add_marker(pytest.mark.torch)


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
