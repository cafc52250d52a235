"""Simulator sequences for a benchmark, made with ``python -m datamodules.synthetic generate``
(a separate process per sequence) unless the folder already holds one."""

from __future__ import annotations

import shlex
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from benchmarks.common import ROOT
from c3f_slam.io import Sequence


@dataclass(frozen=True)
class SimSequence:
    """Settings of one simulator sequence: a preset with its seed, frame count and square frame
    size (pixels), plus generator overrides (``part.field=value`` for ``--set``, lengths in metres)."""

    preset: str
    seed: int
    frames: int
    size: int
    overrides: tuple[str, ...] = ()

    def command(self, out: Path, overwrite: bool = False) -> list[str]:
        """The generator's command line that writes this sequence to ``out``."""
        cmd = [sys.executable, "-m", "datamodules.synthetic", "generate", "--preset", self.preset]
        for kv in (f"seed={self.seed}", f"path.frames={self.frames}", f"camera.width={self.size}",
                   f"camera.height={self.size}", *self.overrides):
            cmd += ["--set", kv]
        cmd += ["--out", str(out), "--no-progress"]
        return cmd + ["--overwrite"] if overwrite else cmd


def ensure_sequence(spec: SimSequence, out: Path, *, overwrite: bool = False, echo: bool = False,
                    require_frames: bool = False) -> Path:
    """Generate ``spec`` into ``out`` unless ``out`` already holds a sequence (a camera.json); returns ``out``.

    ``overwrite``: let the generator replace a non-empty ``out`` that holds no sequence;
    ``echo``: print the command first; ``require_frames``: an existing sequence with another
    frame count is an error (one line naming ``out``) instead of being used as it is.
    """
    if (out / "camera.json").is_file():
        if require_frames:
            n = len(Sequence(out))
            if n != spec.frames:
                raise SystemExit(f"{out}: holds {n} frames, not --frames {spec.frames}; use another --out")
        return out
    cmd = spec.command(out, overwrite)
    if echo:
        print("+", shlex.join(cmd), flush=True)
    subprocess.run(cmd, cwd=ROOT, check=True)
    return out
