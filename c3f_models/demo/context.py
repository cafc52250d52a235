"""The demo folder's layout and the one way the demo runs a project command (a subprocess
whose output goes to ``DIR/logs/NAME.log``)."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from c3f_models.demo.config import DemoConfig
from c3f_slam.errors import InputError

REPO = Path(__file__).resolve().parents[2]  # the checkout: configs/ lives here
CONFIGS = REPO / "configs"

_MODELS = ["--depth-model", "{models}/depthnet/depthnet.onnx", "--feature-model", "{models}/contrafeat/contrafeat.onnx"]
#: SLAM configurations of the held-out sequence: name -> (title, c3f_slam run options)
SLAM_RUNS: dict[str, tuple[str, list[str]]] = {
    "paper": ("predicted depth + ContraFeat (the paper's configuration)", _MODELS),
    "gt_sift": ("ground-truth depth + SIFT (RGB-D reference)", ["--depth-source", "files", "--descriptors", "sift"]),
    "odometry": ("frame-to-frame odometry, predicted depth + ContraFeat", [*_MODELS, "--baseline", "odometry"]),
}


class StageFailed(Exception):
    """A command of a stage failed; the message is one line (the command's last error line)."""


@dataclass(frozen=True)
class DemoContext:
    """Where everything of one demo run lives (all under ``root``)."""

    root: Path
    cfg: DemoConfig

    @property
    def train_data(self) -> Path:
        return self.root / "data" / "train"

    @property
    def test_seq(self) -> Path:
        return self.root / "data" / "test" / "heldout"

    @property
    def models(self) -> Path:
        return self.root / "models"

    def run_dir(self, model: str) -> Path:
        """The TensorBoard/checkpoint folder of a training run (``depthnet`` or ``contrafeat``)."""
        return self.root / "runs" / model

    def version_dir(self, model: str) -> Path:
        return self.run_dir(model) / "tb" / "version_0"

    def slam_dir(self, name: str) -> Path:
        return self.root / "slam" / name

    def log(self, name: str) -> Path:
        return self.root / "logs" / f"{name}.log"

    def run(self, log_name: str, args: list[str]) -> None:
        """Run ``python ARGS`` from the checkout, appending its output to ``logs/LOG_NAME.log``;
        :class:`StageFailed` with the last ``error:`` line (or the last line) on failure."""
        log = self.log(log_name)
        log.parent.mkdir(parents=True, exist_ok=True)
        with log.open("a") as fh:
            fh.write("$ python " + " ".join(args) + "\n")
            fh.flush()
            proc = subprocess.Popen([sys.executable, *args], cwd=REPO, stdout=fh, stderr=subprocess.STDOUT)
            try:
                rc = proc.wait()
            except KeyboardInterrupt:  # the child got the same SIGINT: let it write its partial state
                proc.wait()
                raise
        if rc != 0:
            raise StageFailed(f"{last_error_line(log)} (exit {rc}; log: {log})")


def last_error_line(log: Path) -> str:
    """The last line starting with ``error:`` in ``log``, else its last non-empty line."""
    lines = [ln.strip() for ln in log.read_text(errors="replace").replace("\r", "\n").splitlines() if ln.strip()]
    errors = [ln for ln in lines if ln.startswith("error:")]
    return (errors or lines or ["no output"])[-1]


def check_out_dir(root: Path) -> None:
    """``--out`` must be a folder (or not exist yet)."""
    if root.exists() and not root.is_dir():
        raise InputError(f"--out {root}: exists and is not a folder")
