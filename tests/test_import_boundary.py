"""Import boundaries. c3f_slam, the simulator and the published-data readers and converter must
import where torch cannot be imported (the runtime-only install has no torch). The packages form
layers (c3f_core < c3f_slam < datamodules < export < c3f_models < c3f_demo; benchmarks, tools and tests on
top): no import runs up a layer, and no two modules import each other in a circle."""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

BLOCK_TORCH = r"""
import importlib, pkgutil, sys

class BlockTorch:
    def find_spec(self, name, path=None, target=None):
        if name == "torch" or name.startswith("torch."):
            raise ImportError("torch is blocked in this test")
        return None

sys.meta_path.insert(0, BlockTorch())
try:
    import torch  # noqa: F401
except ImportError:
    pass
else:
    raise SystemExit("the torch block did not work")

import {package}
names = ([m.name for m in pkgutil.walk_packages({package}.__path__, "{package}.")]
         if hasattr({package}, "__path__") else [])
for name in names:
    importlib.import_module(name)
assert not any(m == "torch" or m.startswith("torch.") for m in sys.modules), "torch got imported"
print(len(names) + 1, "modules imported without torch")
"""


def _run(package: str) -> str:
    out = subprocess.run(
        [sys.executable, "-c", BLOCK_TORCH.replace("{package}", package)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    return out.stdout


@pytest.mark.e2e
@pytest.mark.parametrize("package", ["c3f_core", "c3f_slam", "datamodules.synthetic", "datamodules.formats",
                                     "datamodules.convert", "datamodules.__main__"])
def test_imports_without_torch(package):
    assert "modules imported without torch" in _run(package)


@pytest.mark.torch
def test_block_really_blocks():
    """The same harness fails on a package that needs torch (so the test above can fail)."""
    pytest.importorskip("lightning")  # the runtime-only install lacks more than torch
    out = subprocess.run(
        [sys.executable, "-c", BLOCK_TORCH.replace("{package}", "c3f_models")],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode != 0 and "torch is blocked" in out.stderr


# ------------------------------------------------------------------ layers
#: the packages from the bottom up; a module may import its own layer and those below, never one above
LAYERS = ("c3f_core", "c3f_slam", "datamodules", "export", "c3f_models", "c3f_demo")


def _module_name(path: Path, root: Path) -> str:
    parts = path.relative_to(root).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path) -> list[tuple[int, str]]:
    """(line, module) of every absolute import in the file: top level, in functions, under
    TYPE_CHECKING alike (``from a import b`` yields ``a`` and ``a.b``)."""
    import ast

    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found += [(node.lineno, node.module)] + [(node.lineno, f"{node.module}.{a.name}") for a in node.names]
    return found


def layer_violations(root: Path, layers: tuple[str, ...] = LAYERS) -> list[str]:
    """``file:line imports X (layer j above i)`` for each import that runs up the layers."""
    rank = {name: i for i, name in enumerate(layers)}
    out = []
    for pkg in layers:
        for path in sorted((root / pkg).rglob("*.py")):
            for line, mod in _imports(path):
                top = mod.split(".")[0]
                if rank.get(top, -1) > rank[pkg]:
                    out.append(f"{path.relative_to(root)}:{line} imports {mod} ({top} is above {pkg})")
    return sorted(set(out))


def import_cycles(root: Path, packages: tuple[str, ...] = LAYERS) -> list[list[str]]:
    """Groups of project modules that import each other in a circle (any import statement; a
    submodule importing its own package is not an edge)."""
    modules = {_module_name(p, root): p for pkg in packages for p in (root / pkg).rglob("*.py")}
    edges = {m: {t for _, t in _imports(p) if t in modules and t != m and not m.startswith(t + ".")}
             for m, p in modules.items()}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    cycles: list[list[str]] = []

    def visit(v: str) -> None:  # Tarjan's strongly connected components
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in edges[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                cycles.append(sorted(group))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return cycles


def test_packages_import_only_their_layer_and_below():
    assert layer_violations(ROOT) == []


def test_no_import_circle_between_modules():
    assert import_cycles(ROOT) == []


def test_layer_and_circle_checks_can_fail(tmp_path):
    """The two checks on a planted tree: an upward import and a circle are both reported."""
    for pkg in LAYERS:
        (tmp_path / pkg).mkdir()
        (tmp_path / pkg / "__init__.py").write_text("")
    (tmp_path / "c3f_slam" / "a.py").write_text("def f():\n    from c3f_models import b\n")
    (tmp_path / "datamodules" / "x.py").write_text("import datamodules.y\n")
    (tmp_path / "datamodules" / "y.py").write_text("from datamodules import x\n")
    assert layer_violations(tmp_path) == ["c3f_slam/a.py:2 imports c3f_models (c3f_models is above c3f_slam)",
                                          "c3f_slam/a.py:2 imports c3f_models.b (c3f_models is above c3f_slam)"]
    assert import_cycles(tmp_path) == [["datamodules.x", "datamodules.y"]]


def test_the_torch_mark_finds_files_that_need_the_training_stack(tmp_path):
    """conftest's rule on planted test files: imports of the stack (also inside a test, and the
    torch-needing parts of datamodules) and ``-m c3f_models`` subprocesses count; the rest not."""
    from tests.conftest import needs_training_stack

    cases = {"imports_torch": "def test():\n    import torch\n",
             "lightning": "from lightning.pytorch import Trainer\n",
             "datamodule": "from datamodules.sequence import C3FSequenceDataModule\n",
             "datamodule_from_package": "from datamodules import base\n",
             "subprocess": "import sys\nARGS = [sys.executable, '-m', 'c3f_demo', '--quick']\n",
             "runtime": "from c3f_slam.pipeline import SlamConfig\nimport numpy\n",
             "simulator": "from datamodules.synthetic import generate_sequence\nfrom datamodules import formats\n",
             "name_only": "LAYERS = ('c3f_models', 'c3f_demo')\n"}
    found = {}
    for name, text in cases.items():
        (tmp_path / f"test_{name}.py").write_text(text)
        found[name] = needs_training_stack(tmp_path / f"test_{name}.py")
    assert found == {"imports_torch": True, "lightning": True, "datamodule": True, "datamodule_from_package": True,
                     "subprocess": True, "runtime": False, "simulator": False, "name_only": False}
