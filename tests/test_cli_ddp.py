"""Distributed data-parallel training on CPU: ``configs/trainer/ddp.yaml`` with two processes
started by torchrun (gloo backend), as on a cluster node. The run writes one run folder (rank 0),
its checkpoint resumes under DDP into the same folder with the step numbers continuing, and
exports from a single process with the run's saved config. Each process trains on its own share
of every epoch (:class:`datamodules.resumable.ResumableSampler`), a share a checkpoint resumes.

Every torchrun gets a timeout: two processes that wait on each other forever (a collective one of
them never reaches) fail the test instead of hanging CI; the whole process group is killed."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from c3f_models.cli import main
from datamodules.resumable import ResumableSampler

ROOT = Path(__file__).resolve().parents[1]
TIMEOUT_S = 300  #: one torchrun (two processes); about 30 s on the 2-core CI machine


def _torchrun(args: list[str], processes: int = 2) -> subprocess.CompletedProcess:
    """``torchrun --standalone --nproc_per_node N -m c3f_models ARGS`` from the repository root;
    on a timeout the whole process group (torchrun and its workers) is killed and the test fails."""
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", str(processes),
           "-m", "c3f_models", *args]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)
    try:
        out, _ = proc.communicate(timeout=TIMEOUT_S)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, _ = proc.communicate()
        pytest.fail(f"torchrun did not end within {TIMEOUT_S} s (deadlocked?):\n{out[-3000:]}")
    return subprocess.CompletedProcess(cmd, proc.returncode, out, "")


def _options(data: Path, out: Path, batch: int = 2) -> list[str]:
    """The DDP preset on CPU: gloo, 32-bit, no SyncBatchNorm (CUDA only), small frames."""
    return [
        "fit", "--config", "configs/trainer/ddp.yaml", "--config", "configs/depthnet/small.yaml",
        "--trainer.accelerator", "cpu", "--trainer.devices", "2", "--trainer.precision", "32-true",
        "--trainer.sync_batchnorm", "false", "--trainer.log_every_n_steps", "1",
        "--trainer.limit_val_batches", "1", "--trainer.num_sanity_val_steps", "0",
        "--trainer.enable_progress_bar", "false", "--trainer.enable_model_summary", "false",
        "--data.data_dir", str(data), "--data.frames.size", "[32, 32]", "--data.loader.batch_size", str(batch),
        "--trainer.default_root_dir", str(out), "--trainer.logger.init_args.save_dir", str(out),
    ]


def _train_steps(run_dir: Path) -> list[int]:
    acc = EventAccumulator(str(run_dir))
    acc.Reload()
    return sorted(e.step for e in acc.Scalars("train/loss"))


def _ckpt(path: Path) -> dict:
    return torch.load(path, map_location="cpu", weights_only=True)


def _loader_state(ckpt: dict) -> dict:
    return ckpt["loops"]["fit_loop"]["state_dict"]["combined_loader"][0]


@pytest.mark.e2e
@pytest.mark.long
def test_ddp_fit_on_two_cpu_processes_resumes_and_exports(plane_dataset, tmp_path, monkeypatch):
    out = tmp_path / "run"
    r = _torchrun([*_options(plane_dataset, out), "--trainer.max_steps", "2"])
    assert r.returncode == 0, r.stdout[-3000:]
    assert "Starting with 2 processes" in r.stdout and "distributed_backend=gloo" in r.stdout
    assert sorted(p.name for p in (out / "tb").iterdir()) == ["version_0"], "rank 1 made a run folder of its own"
    run = out / "tb" / "version_0"
    ckpt = run / "checkpoints" / "last.ckpt"
    first = _ckpt(ckpt)
    assert first["global_step"] == 2
    # 4 training samples, 2 processes of batch 2: one step an epoch, each process on its half
    assert _loader_state(first) == {"seed": 42, "epoch": 2, "position": 0, "length": 4, "replicas": 2}
    assert (run / "config.yaml").is_file() and _train_steps(run) == [0, 1]

    r = _torchrun([*_options(plane_dataset, out), "--trainer.max_steps", "4", "--ckpt_path", str(ckpt)])
    assert r.returncode == 0, r.stdout[-3000:]
    assert "Restored all states from the checkpoint" in r.stdout
    assert sorted(p.name for p in (out / "tb").iterdir()) == ["version_0"], "the resumed run made a new version"
    assert _ckpt(ckpt)["global_step"] == 4 and _train_steps(run) == [0, 1, 2, 3]

    # the run's config (2 processes, DDPStrategy) exports from one process, as a single-process run's does
    monkeypatch.chdir(ROOT)
    exported = tmp_path / "onnx"
    main(["export", "--config", str(run / "config.yaml"), "--ckpt_path", str(ckpt), "--output_dir", str(exported),
          "--graphs", "[depth]", "--num_frames", "2"])
    assert (exported / "depthnet.onnx").stat().st_size > 1e6 and (exported / "export.json").is_file()


@pytest.mark.slow
def test_ddp_resumed_in_mid_epoch_equals_uninterrupted(plane_dataset, tmp_path):
    """2 + 2 steps resumed under DDP give the weights of 4 uninterrupted DDP steps, bit for bit
    (batch 1: two steps an epoch per process, so the interruption falls in mid-epoch)."""
    whole, parts = tmp_path / "whole", tmp_path / "parts"
    for out, steps, resume in ((whole, 4, []), (parts, 2, []), (parts, 4, ["--ckpt_path", str(
            parts / "tb" / "version_0" / "checkpoints" / "last.ckpt")])):
        r = _torchrun([*_options(plane_dataset, out, batch=1), "--trainer.max_steps", str(steps), *resume])
        assert r.returncode == 0, r.stdout[-3000:]
    a = _ckpt(whole / "tb" / "version_0" / "checkpoints" / "last.ckpt")
    b = _ckpt(parts / "tb" / "version_0" / "checkpoints" / "last.ckpt")
    assert a["global_step"] == b["global_step"] == 4
    differ = [k for k in a["state_dict"] if not torch.equal(a["state_dict"][k], b["state_dict"][k])]
    assert not differ, f"{len(differ)} of {len(a['state_dict'])} tensors differ, e.g. {differ[0]}"


@pytest.mark.parametrize("length", [7, 8])
def test_sampler_shares_cover_the_single_process_order_and_resume(length):
    """The processes' shares interleave into the single-process order (padded from its start to a
    multiple of the processes: all take the same number of steps); a state saved in mid-epoch
    records the position in the epoch's order and each process continues its own share there."""
    single = ResumableSampler(length, seed=5, keyed=True)
    single.set_epoch(1)
    order = list(single)
    shares = []
    for rank in range(2):
        s = ResumableSampler(length, seed=5, keyed=True, replicas=2, rank=rank)
        s.set_epoch(1)
        shares.append(list(s))
    assert len(shares[0]) == len(shares[1]) == -(-length // 2)
    interleaved = [x for pair in zip(*shares) for x in pair]
    assert interleaved[:length] == order and interleaved[length:] == order[:len(interleaved) - length]

    state = ResumableSampler(length, seed=5, replicas=2, rank=1).state_dict(position=2, epoch=1)
    assert state["position"] == 4 and state["replicas"] == 2  # 2 samples of each of the 2 shares
    resumed = ResumableSampler(length, seed=0, keyed=True, replicas=2, rank=1)
    resumed.load_state_dict(state)
    assert list(resumed) == shares[1][2:]
    one = ResumableSampler(length, seed=0, keyed=True)  # one process continues at the same sample
    one.load_state_dict(state)
    assert list(one) == order[4:]
    assert np.array_equal(single.order(1), ResumableSampler(length, seed=5, replicas=2, rank=0).order(1))
