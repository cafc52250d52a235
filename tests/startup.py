"""What a command imports: ``python -m MODULE ARGS`` run in a fresh interpreter, and the
top-level packages it had loaded when it ended (for the tests that commands which need no torch,
Lightning or Open3D start without them)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: run as ``python -c SCRIPT MODULE ARGS``: the module as ``python -m`` runs it, then the report
SCRIPT = """
import json, runpy, sys
sys.argv = sys.argv[1:]
code = 0
try:
    runpy.run_module(sys.argv[0], run_name="__main__", alter_sys=True)
except SystemExit as exc:
    code = exc.code or 0
print("\\nLOADED " + json.dumps({"code": code, "packages": sorted({m.split(".")[0] for m in sys.modules})}))
"""


def packages_loaded_by(module: str, *args: str, status: int = 0) -> set[str]:
    """The top-level packages ``python -m MODULE ARGS`` imported (run from the repository root);
    AssertionError when the command ends with another exit status than ``status``."""
    out = subprocess.run([sys.executable, "-c", SCRIPT, module, *args], cwd=ROOT, capture_output=True, text=True,
                         timeout=300)
    lines = [ln for ln in out.stdout.splitlines() if ln.startswith("LOADED ")]
    assert out.returncode == 0 and lines, out.stderr[-2000:]
    report = json.loads(lines[-1].removeprefix("LOADED "))
    assert report["code"] == status, (report["code"], out.stderr[-2000:])
    return set(report["packages"])
