"""Running a zoo recipe (:mod:`c3f_models.zoo.recipes`) in a work folder, resumably.

``python -m c3f_models zoo train NAME [--work DIR] [--max-minutes M]`` runs, each stage skipped
when already done:

1. ``simulate``: the recipe's sequences into ``WORK/data`` (the project's own generator; a
   published-data recipe reads the ``--data`` folder instead);
2. ``fit``: ``python -m c3f_models fit`` with the recipe's config and ``WORK/fit.yaml`` (data,
   split, steps, start weights of a fine-tune, logging into ``WORK/run``); an interrupted fit
   (Ctrl-C, ``--max-minutes``, a killed process) continues exactly from its newest checkpoint;
3. ``package``: the weights in float16 (``weights.safetensors``), their ONNX export (float16
   storage, float32 compute, parity-checked), the held-out evaluation and the model card, written
   into the zoo (:mod:`c3f_models.zoo.package`).

``WORK/recipe.json`` records each fit chunk's wall time and machine, so the card states the
recipe's total time.
"""

from __future__ import annotations

import json
import os
import platform
import signal
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import yaml

from c3f_core.errors import InputError
from c3f_models.zoo.recipes import Recipe, SimSpec

REPO = Path(__file__).resolve().parents[2]
CHECKPOINT_EVERY = 250  #: optimiser steps between checkpoints (what an interruption can lose at most)


@dataclass(frozen=True)
class RecipeRun:
    """The work folder of one recipe (everything under ``work``); ``init``: the verified weights
    file that starts the fit (:attr:`Recipe.init`); ``source``: a published-data recipe's folder."""

    recipe: Recipe
    work: Path
    init: Path | None = None
    source: Path | None = None

    @property
    def data(self) -> Path:
        return self.source if self.source is not None else self.work / "data"

    @property
    def run_dir(self) -> Path:
        return self.work / "run"

    @property
    def checkpoints(self) -> Path:
        return self.run_dir / "tb" / "version_0" / "checkpoints"

    @property
    def config(self) -> Path:
        """The resolved config the fit saved (LightningCLI's ``config.yaml``)."""
        return self.run_dir / "tb" / "version_0" / "config.yaml"

    @property
    def fit_yaml(self) -> Path:
        return self.work / "fit.yaml"

    @property
    def state_file(self) -> Path:
        return self.work / "recipe.json"

    @property
    def log(self) -> Path:
        return self.work / "fit.log"

    def read_state(self) -> dict:
        if self.state_file.is_file():
            return json.loads(self.state_file.read_text())
        return {"recipe": self.recipe.name, "chunks": []}

    def write_state(self, state: dict) -> None:
        tmp = self.state_file.with_suffix(".tmp")
        tmp.write_text(json.dumps(state, indent=2) + "\n")
        os.replace(tmp, self.state_file)


def default_work(name: str) -> Path:
    return REPO / "runs" / "zoo" / name


# ---------------------------------------------------------------------------------------- simulate
def run_module(args: list[str], what: str) -> subprocess.CompletedProcess:
    """``python ARGS`` in the repository; InputError ``WHAT failed: <its last error line>`` when it fails."""
    done = subprocess.run([sys.executable, *args], cwd=REPO, capture_output=True, text=True)
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or ["(no output)"])[-1]
        raise InputError(f"{what} failed: {last[-300:]}")
    return done


def generate_command(spec: SimSpec, size: int, out: Path) -> list[str]:
    """The simulator's command line that writes ``spec`` with square frames of ``size`` pixels to
    ``out`` (its look's items last)."""
    sets = (f"seed={spec.seed}", f"path.frames={spec.frames}", f"camera.width={size}", f"camera.height={size}",
            f"path.coverage={spec.coverage}", *spec.look_items)
    return [sys.executable, "-m", "datamodules.synthetic", "generate", "--preset", spec.preset,
            *(arg for kv in sets for arg in ("--set", kv)), "--out", str(out), "--no-progress", "--overwrite"]


def simulate(specs: tuple[SimSpec, ...], size: int, root: Path, jobs: int = 2) -> list[Path]:
    """Generate each sequence into ``root/NAME`` unless it is there complete (``camera.json`` and
    ``frames`` RGB files); returns the folders."""

    def one(spec: SimSpec) -> Path:
        out = root / spec.name
        if (out / "camera.json").is_file() and len(list((out / "rgb").glob("*.png"))) == spec.frames:
            return out
        run_module(generate_command(spec, size, out)[1:], f"simulate {spec.name}")
        return out

    root.mkdir(parents=True, exist_ok=True)
    with ThreadPoolExecutor(max_workers=max(1, jobs)) as pool:
        return list(pool.map(one, specs))


# ---------------------------------------------------------------------------------------- fit
def write_fit_yaml(run: RecipeRun, steps: int) -> Path:
    """The recipe's last config file: data folder and split (a published data set: its data
    module's own), steps, start weights, logging into ``WORK/run``."""
    r = run.recipe
    split = {"train": [s.name for s in r.train], "val": [s.name for s in r.val], "test": [],
             "val_fraction": 0.0, "test_fraction": 0.0}
    data = {"data_dir": str(run.data)} if r.dataset else {"data_dir": str(run.data), "split": split}
    cfg = {
        "trainer": {
            "max_steps": steps, "default_root_dir": str(run.run_dir),
            "callbacks": [
                {"class_path": "lightning.pytorch.callbacks.ModelCheckpoint",
                 "init_args": {"save_last": True, "every_n_train_steps": min(CHECKPOINT_EVERY, steps)}},
                {"class_path": "lightning.pytorch.callbacks.LearningRateMonitor",
                 "init_args": {"logging_interval": "step"}},
            ],
            "logger": {"class_path": "lightning.pytorch.loggers.TensorBoardLogger",
                       "init_args": {"save_dir": str(run.run_dir), "name": "tb", "version": 0}},
        },
        "data": {"init_args": data},
    }
    if run.init is not None:
        cfg["model"] = {"init_args": {"init_weights": str(run.init)}}
    run.work.mkdir(parents=True, exist_ok=True)
    run.fit_yaml.write_text(yaml.safe_dump(cfg, sort_keys=False))
    return run.fit_yaml


def checkpoint_step(path: Path) -> int:
    """The optimiser step a Lightning checkpoint was saved at (safe loader, tensors mapped)."""
    from c3f_models.checkpoints import read_checkpoint

    return int(read_checkpoint(path, "checkpoint", mmap=True).get("global_step", -1))


def newest_checkpoint(run: RecipeRun) -> tuple[Path | None, int]:
    """The checkpoint of ``WORK/run`` with the most steps (``last.ckpt``, ``interrupted.ckpt``,
    or a periodic one) and its step; (None, 0) before the first."""
    best: tuple[Path | None, int] = (None, 0)
    for path in sorted(run.checkpoints.glob("*.ckpt")) if run.checkpoints.is_dir() else []:
        step = checkpoint_step(path)
        if step > best[1]:
            best = (path, step)
    return best


def fit_command(run: RecipeRun, steps: int, trainer_config: Path | None = None) -> list[str]:
    """``python -m c3f_models fit`` of the recipe (``trainer_config``, e.g. ``configs/trainer/gpu.yaml``,
    composed after the recipe's config), resuming from the newest checkpoint if any."""
    extra = ["--config", str(trainer_config)] if trainer_config is not None else []
    cmd = [sys.executable, "-m", "c3f_models", "fit", "--config", str(REPO / run.recipe.config), *extra,
           "--config", str(write_fit_yaml(run, steps))]
    ckpt, _ = newest_checkpoint(run)
    return cmd + (["--ckpt_path", str(ckpt)] if ckpt is not None else [])


def fit(run: RecipeRun, steps: int, max_minutes: float | None = None, trainer_config: Path | None = None) -> bool:
    """Train (or continue) up to ``steps``; True when done. With ``max_minutes`` the fit is
    interrupted (SIGINT: it saves ``interrupted.ckpt``) after that long and False is returned.
    The chunk's wall time is recorded in ``WORK/recipe.json``."""
    _, step = newest_checkpoint(run)
    if step >= steps:
        return True
    start = time.time()
    run.work.mkdir(parents=True, exist_ok=True)
    with open(run.log, "a") as log:
        log.write(f"\n# {time.strftime('%Y-%m-%d %H:%M:%S')} from step {step}\n")
        log.flush()
        proc = subprocess.Popen(fit_command(run, steps, trainer_config), cwd=REPO, stdout=log, stderr=subprocess.STDOUT,
                                start_new_session=True, preexec_fn=_default_sigint)
        try:
            code = proc.wait(timeout=None if max_minutes is None else 60.0 * max_minutes)
        except subprocess.TimeoutExpired:
            code = _interrupt(proc)
        except KeyboardInterrupt:
            code = _interrupt(proc)
            _record_chunk(run, start, step)
            raise
    _record_chunk(run, start, step)
    _, reached = newest_checkpoint(run)
    if code not in (0, 130):
        raise InputError(f"fit of {run.recipe.name} failed (exit {code}); see {run.log}")
    return reached >= steps


def _default_sigint() -> None:
    """In the fit's process, before it starts: Ctrl-C handled as usual even when this command
    runs in the background (a shell starts background jobs with SIGINT ignored, and Python
    then installs no handler: the fit could not save its interrupt checkpoint)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _interrupt(proc: subprocess.Popen) -> int:
    """One SIGINT to the fit's process group, then wait for its interrupt checkpoint."""
    os.killpg(proc.pid, signal.SIGINT)
    return proc.wait()


def _record_chunk(run: RecipeRun, start: float, from_step: int) -> None:
    state = run.read_state()
    _, reached = newest_checkpoint(run)
    state["chunks"].append({"from_step": from_step, "to_step": reached, "wall_s": round(time.time() - start, 1),
                            "machine": machine(), "date": time.strftime("%Y-%m-%d")})
    run.write_state(state)


def machine() -> str:
    """A short description of this machine: CPU count and model, or the GPU."""
    cpu = platform.processor() or platform.machine()
    try:
        import torch

        if torch.cuda.is_available():
            return f"1x {torch.cuda.get_device_name(0)} (CUDA)"
    except ImportError:
        pass
    return f"{os.cpu_count()} CPU cores ({cpu}), no GPU"


__all__ = ["RecipeRun", "default_work", "fit", "fit_command", "newest_checkpoint", "simulate"]
