"""Calls name their arguments: no call in the project passes more than MAX_POSITIONAL arguments by
position (docs/design.md, Overview). A long positional call is where two arguments of the same
type get swapped without an error."""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("c3f_core", "c3f_slam", "c3f_models", "datamodules", "export", "c3f_demo", "benchmarks", "tests", "tools")
MAX_POSITIONAL = 6
#: libraries whose functions keep their own conventions (numpy, OpenCV, torch, Open3D, ...)
FOREIGN = {"np", "cv2", "torch", "F", "nn", "o3d", "o3c", "plt", "ax", "math", "struct", "os", "subprocess", "sys"}
#: calls that may pass more: Open3D's TSDF integration (its own signature); camera intrinsics in
#: their conventional order (as OpenCV's); a command line's arguments (``*args: str``)
ALLOWED = {"self._vbg.integrate", "OmniCamera", "PinholeCamera", "_batch"}


def long_positional_calls(root: Path, packages=PACKAGES, limit: int = MAX_POSITIONAL) -> list[str]:
    """``file:line name (n positional)`` for each call with more than ``limit`` positional arguments."""
    found = []
    for pkg in packages:
        for path in sorted((root / pkg).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                if not isinstance(node, ast.Call):
                    continue
                n = sum(not isinstance(a, ast.Starred) for a in node.args)
                name = ast.unparse(node.func)
                if n > limit and name.split(".")[0] not in FOREIGN and name not in ALLOWED:
                    found.append(f"{path.relative_to(root)}:{node.lineno} {name} ({n} positional)")
    return found


def test_no_call_passes_many_arguments_by_position():
    assert long_positional_calls(ROOT) == []


def test_the_check_finds_a_long_call(tmp_path):
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "m.py").write_text("f(1, 2, 3, 4, 5, 6, 7)\nf(1, 2, 3, 4, 5, 6, g=7)\n"
                                          "np.f(1, 2, 3, 4, 5, 6, 7)\n")
    assert long_positional_calls(tmp_path, ("pkg",)) == ["pkg/m.py:1 f (7 positional)"]
