"""c3f_slam, the simulator and the published-data readers and converter must import where
torch cannot be imported (the runtime-only install has no torch)."""

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


@pytest.mark.parametrize("package", ["c3f_slam", "datamodules.synthetic", "datamodules.formats", "datamodules.convert",
                                     "datamodules.__main__"])
def test_imports_without_torch(package):
    assert "modules imported without torch" in _run(package)


def test_block_really_blocks():
    """The same harness fails on a package that needs torch (so the test above can fail)."""
    out = subprocess.run(
        [sys.executable, "-c", BLOCK_TORCH.replace("{package}", "c3f_models")],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode != 0 and "torch is blocked" in out.stderr
