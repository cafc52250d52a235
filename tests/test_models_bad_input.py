"""Bad input to ``python -m c3f_models fit`` and ``export``: exit status 2, one ``error:`` line
naming the file or option, the output folder as it was (an earlier export, a run folder) or
nothing written (tests/bad_input.py); Ctrl-C (a real SIGINT) during ``fit`` saves the steps done.

The cases of the former ``benchmarks/fault_injection.py`` that no other test covered at the
command line; the rest are in test_cli_fit.py (a resume overriding a model option, Ctrl-C in a
training step), test_cli_refusals.py, test_datamodule_config.py (``batch_size 0``) and
test_export.py. Every case starts from one 1-step DepthNet fit and one 1-step ContraFeat fit of
the small configs (configs/trainer/cpu_smoke.yaml), made once for the module."""

from __future__ import annotations

import re
import shutil
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest
import torch

from c3f_models.cli import main
from tests.bad_input import Case, check_refused, error_line, interrupt

pytestmark = pytest.mark.e2e  # the fits and every case run the command line end to end

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = {"depth": "configs/depthnet/small.yaml", "feat": "configs/contrafeat/small.yaml"}


def fit_args(data: Path, kind: str, root: Path, steps: int = 1) -> list[str]:
    """A smoke fit of ``kind`` (depth / feat) on ``data`` at 32x32, logging under ``root``."""
    gaps = ["--data.sampling.gaps", "[1, 2]"] if kind == "feat" else []  # the sequences have 6 frames
    return ["fit", "--config", str(ROOT / "configs/trainer/cpu_smoke.yaml"), "--config", str(ROOT / CONFIGS[kind]),
            "--data.data_dir", str(data), "--data.frames.size", "[32, 32]", *gaps, "--trainer.max_steps", str(steps),
            "--trainer.default_root_dir", str(root), "--trainer.logger.init_args.save_dir", str(root),
            "--trainer.enable_progress_bar", "false", "--trainer.enable_model_summary", "false"]


@dataclass(frozen=True)
class Fits:
    """The data and the 1-step fits (``ROOT/fit_depth``, ``ROOT/fit_feat``) the cases start from."""

    data: Path
    root: Path

    def folder(self, kind: str) -> Path:
        return self.root / f"fit_{kind}"

    def run(self, kind: str) -> Path:
        return self.folder(kind) / "tb" / "version_0"

    def ckpt(self, kind: str) -> Path:
        return self.run(kind) / "checkpoints" / "last.ckpt"


@pytest.fixture(scope="module")
def fits(sim_dataset, tmp_path_factory) -> Fits:
    fx = Fits(sim_dataset, tmp_path_factory.mktemp("fits"))
    for kind in CONFIGS:
        main(fit_args(fx.data, kind, fx.folder(kind)))
        assert fx.ckpt(kind).is_file()
    return fx


def _export(fx: Fits, tmp: Path, ckpt: Path, *names: str) -> Case:
    """Export with the DepthNet run's config and ``ckpt`` into a folder holding an earlier export
    (its files stand for one: nothing may touch them)."""
    out = tmp / "exported"
    out.mkdir()
    for name in ("depthnet.onnx", "posenet.onnx", "export.json"):
        (out / name).write_bytes(f"earlier {name}".encode())
    argv = ["export", "--config", str(fx.run("depth") / "config.yaml"), "--ckpt_path", str(ckpt),
            "--output_dir", str(out)]
    return Case(main, argv, out, ("--ckpt_path", str(ckpt), *names))


def export_garbage_checkpoint(fx: Fits, tmp: Path) -> Case:
    (tmp / "garbage.ckpt").write_bytes(b"garbage\n" * 100)
    return _export(fx, tmp, tmp / "garbage.ckpt", "is not a torch checkpoint")


def export_truncated_checkpoint(fx: Fits, tmp: Path) -> Case:
    data = fx.ckpt("depth").read_bytes()
    (tmp / "half.ckpt").write_bytes(data[: len(data) // 2])
    return _export(fx, tmp, tmp / "half.ckpt", "is not a torch checkpoint")


def export_checkpoint_of_another_model(fx: Fits, tmp: Path) -> Case:
    return _export(fx, tmp, fx.ckpt("feat"), "holds a ContraFeat",
                   "the config's model is c3f_models.depth.module.DepthNet")


class _Payload:
    """Unpickling this creates the file ``marker`` (a stand-in for arbitrary code)."""

    def __init__(self, marker: Path):
        self.marker = str(marker)

    def __reduce__(self):
        return open, (self.marker, "w")


def fit_init_weights_with_a_payload(fx: Fits, tmp: Path) -> Case:
    marker, weights = tmp / "PAYLOAD_RAN", tmp / "payload.ckpt"
    torch.save({"state_dict": {"x": _Payload(marker)}}, weights)
    out = tmp / "runs"
    return Case(main, [*fit_args(fx.data, "depth", out), "--model.init_args.init_weights", str(weights)], out,
                ("model.init_weights", str(weights), "refused, nothing in it ran"), absent=(marker,))


def fit_missing_pretrained_weights(fx: Fits, tmp: Path) -> Case:
    out = tmp / "runs"
    missing = tmp / "missing.pth"
    return Case(main, [*fit_args(fx.data, "depth", out), "--model.network.pretrained_path", str(missing)], out,
                ("model.network.pretrained_path", str(missing), "file not found"))


def fit_resume_with_another_model_option(fx: Fits, tmp: Path) -> Case:
    out = tmp / "runs"
    shutil.copytree(fx.folder("depth"), out)
    ckpt = out / "tb" / "version_0" / "checkpoints" / "last.ckpt"
    return Case(main, [*fit_args(fx.data, "depth", out, steps=2), "--ckpt_path", str(ckpt),
                       "--model.loss.lambda_dc", "0.5"], out,
                ("--ckpt_path", "model.loss.lambda_dc: 0.1 in the checkpoint, 0.5 given"))


CASES: dict[str, Callable[[Fits, Path], Case]] = {
    "export: --ckpt_path a garbage file": export_garbage_checkpoint,
    "export: checkpoint cut at half its bytes": export_truncated_checkpoint,
    "export: ContraFeat checkpoint, DepthNet config": export_checkpoint_of_another_model,
    "fit: --model.init_args.init_weights a pickle with a payload": fit_init_weights_with_a_payload,
    "fit: --model.network.pretrained_path a missing file": fit_missing_pretrained_weights,
    "fit: resume with a conflicting --model.loss.lambda_dc": fit_resume_with_another_model_option,
}


@pytest.mark.parametrize("make", CASES.values(), ids=CASES.keys())
def test_bad_input_is_one_line_and_changes_nothing(make, fits, tmp_path, capsys):
    check_refused(make(fits, tmp_path), capsys, only=False)  # Lightning logs its set-up to stderr first


@pytest.mark.slow
def test_ctrl_c_during_fit_saves_the_steps_done(fits, tmp_path):
    """A real SIGINT to ``python -m c3f_models fit`` a few seconds into training: exit 130, one
    error line naming the checkpoint of the steps done, which holds them and resumes."""
    root = tmp_path / "runs"
    cmd = [sys.executable, "-m", "c3f_models", *fit_args(fits.data, "depth", root, steps=1000),
           "--trainer.limit_train_batches", "1000"]
    code, err = interrupt(cmd, lambda: (root / "tb" / "version_0" / "config.yaml").is_file(), delay_s=3.0)
    assert code == 130
    m = re.fullmatch(r"error: interrupted at step (\d+); checkpoint saved: (\S+) \(resume with --ckpt_path (\S+)\)",
                     error_line(err, only=False))
    assert m and m.group(2) == m.group(3) == str(root / "tb" / "version_0" / "checkpoints" / "interrupted.ckpt"), err
    saved = torch.load(m.group(2), map_location="cpu", weights_only=True)
    assert saved["global_step"] == int(m.group(1)) and sorted(p.name for p in (root / "tb").iterdir()) == ["version_0"]
