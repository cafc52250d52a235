"""Every benchmark script at least parses its command line (imports and module-level code
run): benchmarks run outside CI, so a broken script would otherwise go unnoticed."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = sorted((ROOT / "benchmarks").glob("*.py"))


def test_there_are_benchmarks():
    assert len(SCRIPTS) >= 5


@pytest.mark.parametrize("script", SCRIPTS, ids=[s.stem for s in SCRIPTS])
def test_help(script: Path):
    r = subprocess.run([sys.executable, str(script), "--help"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "usage:" in r.stdout


def test_tracking_breaks_reports_a_black_frame(tmp_path):
    """benchmarks/slam_tracking_breaks.py on a tiny sequence with one black frame: the two
    pairs around it are the only broken ones, and the report says why."""
    import cv2
    import numpy as np

    from datamodules.synthetic.fixture import make_tiny_sequence

    seq = make_tiny_sequence(tmp_path / "seq", frames=20, size=128, seed=3)
    frame = sorted((seq / "rgb").iterdir())[10]
    cv2.imwrite(str(frame), np.zeros((128, 128, 3), np.uint8))
    report = tmp_path / "breaks.md"
    r = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "slam_tracking_breaks.py"), str(seq),
                        "--report", str(report)], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    text = report.read_text()
    assert "Broken pairs (no accepted match): 2;" in text, text
    assert "| 10 | - | 0 |" in text and "| 11 | - |" in text and "too few keypoints" in text
