"""The demo folder's layout and the one way the demo runs a project command (a subprocess
whose output goes to ``DIR/logs/NAME.log``)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import IO

from c3f_core.errors import InputError
from c3f_demo.config import DemoConfig

REPO = Path(__file__).resolve().parents[1]  # the checkout: configs/ lives here
CONFIGS = REPO / "configs"

def _predicted(depth_folder: str) -> list[str]:
    """``c3f_slam run`` options of predicted depth (``models/DEPTH_FOLDER``) + ContraFeat."""
    return ["--depth-model", "{models}/" + depth_folder + "/depthnet.onnx",
            "--feature-model", "{models}/contrafeat/contrafeat.onnx"]


def slam_runs(cfg: DemoConfig) -> dict[str, tuple[str, list[str]]]:
    """SLAM configurations of the held-out sequence: name -> (title, ``c3f_slam run`` options;
    ``{models}`` stands for ``DIR/models``). With test-time training on, the paper's configuration
    uses the tuned DepthNet and ``no_ttt`` the pre-trained one. A user's video (no depth files, no
    truth) has these two alone."""
    tuned = cfg.ttt.steps > 0
    runs = {"paper": ("predicted depth" + (" after TTT" if tuned else "") + " + ContraFeat (the paper's configuration)",
                      _predicted("depthnet"))}
    if tuned:
        runs["no_ttt"] = ("predicted depth without TTT + ContraFeat", _predicted("depthnet_pretrained"))
    if cfg.video is not None:
        return runs
    runs["gt_sift"] = ("ground-truth depth + SIFT (RGB-D reference)",
                       ["--depth-source", "files", "--descriptors", "sift"])
    runs["odometry"] = ("frame-to-frame odometry, predicted depth" + (" after TTT" if tuned else "") + " + ContraFeat",
                        [*_predicted("depthnet"), "--set", "mode=odometry"])
    return runs


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
        """The sequence SLAM reconstructs: the simulator's held-out one, or the user's video's frames."""
        return self.root / "data" / "video" if self.cfg.video else self.root / "data" / "test" / "heldout"

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

    @property
    def slam_runs(self) -> dict[str, tuple[str, list[str]]]:
        return slam_runs(self.cfg)

    def log(self, name: str) -> Path:
        return self.root / "logs" / f"{name}.log"

    def run(self, log_name: str, args: list[str]) -> None:
        """Run ``python ARGS`` from the checkout, appending its output to ``logs/LOG_NAME.log``;
        :class:`StageFailed` with the last ``error:`` line (or the last line) on failure."""
        error = self.run_many(log_name, {"": args}, log_names={"": log_name})[""]
        if error is not None:
            raise error

    def run_many(self, log_name: str, commands: dict[str, list[str]],
                 log_names: dict[str, str] | None = None) -> dict[str, StageFailed | None]:
        """Run the ``python ARGS`` of ``commands`` (key -> args) from the checkout,
        :func:`parallel_jobs` at a time, each appending to ``logs/LOG_NAME_KEY.log`` (or
        ``log_names[key]``); returns key -> None (done) or its :class:`StageFailed`. On Ctrl-C no
        further command starts; each running one gets one SIGINT (they run in their own process
        groups, so the terminal's does not reach them twice), is waited for (so it can write its
        partial state, e.g. a fit's checkpoint) up to :data:`INTERRUPT_GRACE_S` seconds, then killed
        (a child that ignores SIGINT, as one started from a background shell does, would otherwise
        run to its end), and KeyboardInterrupt is re-raised."""
        pending, running, results = list(commands.items()), {}, {}
        try:
            while pending or running:
                while pending and len(running) < parallel_jobs():
                    key, args = pending.pop(0)
                    running[key] = _Child.start((log_names or {}).get(key, f"{log_name}_{key}"), self.log, args)
                for key in [k for k, child in running.items() if child.proc.poll() is not None]:
                    results[key] = running.pop(key).finish()
                poll_pause()
        except KeyboardInterrupt:
            for child in running.values():
                child.proc.send_signal(signal.SIGINT)
            for child in running.values():
                try:
                    child.proc.wait(timeout=INTERRUPT_GRACE_S)
                except subprocess.TimeoutExpired:
                    child.proc.kill()
                    child.proc.wait()
                child.finish()
            raise
        return {k: results[k] for k in commands}


#: seconds a command interrupted by run_many has to stop on its own before it is killed
INTERRUPT_GRACE_S = 20.0


@dataclass
class _Child:
    """One running command of :meth:`DemoContext.run_many` and its open log."""

    proc: subprocess.Popen
    log: Path
    fh: IO[str]

    @classmethod
    def start(cls, log_name: str, log_path: Callable[[str], Path], args: list[str]) -> _Child:
        log = log_path(log_name)
        log.parent.mkdir(parents=True, exist_ok=True)
        fh = log.open("a")
        fh.write("$ python " + " ".join(args) + "\n")
        fh.flush()
        # its own process group: a terminal's Ctrl-C reaches only the demo, which forwards exactly one SIGINT
        proc = subprocess.Popen([sys.executable, *args], cwd=REPO, stdout=fh, stderr=subprocess.STDOUT, process_group=0)
        return cls(proc, log, fh)

    def finish(self) -> StageFailed | None:
        """Close the log; the command's StageFailed (None when it exited 0)."""
        self.fh.close()
        rc = self.proc.returncode
        return None if rc == 0 else StageFailed(f"{last_error_line(self.log)} (exit {rc}; log: {self.log})")


def poll_pause() -> None:
    """The pause between two looks at :meth:`DemoContext.run_many`'s children (50 ms)."""
    time.sleep(0.05)


def parallel_jobs() -> int:
    """Commands a stage runs at once: 2 on a machine with 2 or more cores, else 1 (the networks'
    export and the SLAM runs are mostly single-threaded Python; 2 at a time nearly halve the
    wall time on 2 cores)."""
    return 2 if (os.cpu_count() or 1) >= 2 else 1


def last_error_line(log: Path) -> str:
    """The last line starting with ``error:`` in ``log``, else its last non-empty line."""
    lines = [ln.strip() for ln in log.read_text(errors="replace").replace("\r", "\n").splitlines() if ln.strip()]
    errors = [ln for ln in lines if ln.startswith("error:")]
    return (errors or lines or ["no output"])[-1]


def check_out_dir(root: Path) -> None:
    """``--out`` must be a folder (or not exist yet)."""
    if root.exists() and not root.is_dir():
        raise InputError(f"--out {root}: exists and is not a folder")
