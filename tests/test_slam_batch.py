"""``python -m c3f_slam batch``: a data set into one folder of run folders.

A missing and a corrupt sequence among good ones: the good ones finish, the summary names the
bad ones with their one-line errors, the command ends with exit status 2 and one error line; a
rerun skips the complete runs and tries the failed ones again; Ray (a local instance) gives the
same summary as the pool of worker processes. The loop's retry and the defaults of the thread
budget are checked without processes."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from concurrent.futures import Future
from pathlib import Path

import pytest

from c3f_core.errors import InputError
from c3f_slam.batch.cli import budget
from c3f_slam.batch.dataset import BatchItem, find_items
from c3f_slam.batch.job import Job, Row
from c3f_slam.batch.scheduler import BatchLoop
from datamodules.synthetic.fixture import make_tiny_sequence
from tests.startup import packages_loaded_by

ROOT = Path(__file__).resolve().parents[1]
GOOD = ("seq0", "seq1")
#: the rows' fields that do not depend on where or when the run was made
SAME = ("name", "status", "error", "frames", "registered_frames", "registered_share", "unseen_share")


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    """A list file: two tiny sequences (with poses.txt), a corrupt one (no frames), a missing one."""
    root = tmp_path_factory.mktemp("batch")
    for k, name in enumerate(GOOD):
        make_tiny_sequence(root / "data" / name, frames=12, size=96, seed=k)
    (root / "data" / "corrupt" / "rgb").mkdir(parents=True)
    (root / "data" / "corrupt" / "camera.json").write_text("{}")
    listing = root / "data" / "list.txt"
    listing.write_text("# two good, one corrupt, one missing\nseq0\nseq1\ncorrupt\n\nmissing  # not there\n")
    return listing


def _batch(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "c3f_slam", "batch", *args, "--set", "fusion.enabled=false",
                           "--quiet"], cwd=ROOT, capture_output=True, text=True, timeout=600, check=False)


def _runs(out: Path) -> dict[str, dict]:
    return {r["name"]: r for r in json.loads((out / "batch.json").read_text())["runs"]}


@pytest.mark.e2e
def test_bad_sequences_are_reported_the_good_ones_finish_and_a_rerun_skips_them(dataset, tmp_path):
    out = tmp_path / "out"
    r = _batch(str(dataset), "--out", str(out), "--workers", "2", "--threads", "1")
    assert r.returncode == 2, r.stderr[-2000:]
    err = [line for line in r.stderr.splitlines() if line.startswith("error:")]
    assert len(err) == 1 and err[0].startswith("error: 2 of 4 sequences failed: corrupt ("), err
    assert "missing (" in err[0] and "no such file or folder" in err[0]
    runs = _runs(out)
    assert list(runs) == [*GOOD, "corrupt", "missing"]
    for name in GOOD:
        row = runs[name]
        assert row["status"] == "ok" and row["attempts"] == 1 and row["frames"] == 12, row
        assert row["registered_frames"] >= 10 and 0 <= row["ate_rmse_m"] < 0.01, row  # ATE from poses.txt
        assert json.loads((out / name / "summary.json").read_text())["status"] == "ok"
        assert (out / name / "evaluation.json").is_file()
    for name in ("corrupt", "missing"):
        assert runs[name]["status"] == "failed" and runs[name]["attempts"] == 2 and runs[name]["error"] in err[0]
    csv = (out / "batch.csv").read_text().splitlines()
    assert csv[0].startswith("name,sequence,run,status,error") and len(csv) == 5
    index = (out / "index.html").read_text()
    assert index.count('<tr class="ok">') == 2 and index.count('<tr class="failed">') == 2
    assert 'href="seq0/summary.json"' in index and "http" not in index  # self-contained, relative links

    stamps = {n: (out / n / "summary.json").stat().st_mtime_ns for n in GOOD}
    again = _batch(str(dataset), "--out", str(out))
    assert again.returncode == 2 and "2 of 4 sequences failed" in again.stderr
    assert "0 run, 2 complete before, 2 failed" in again.stdout
    reruns = _runs(out)
    assert [reruns[n]["status"] for n in reruns] == ["skipped", "skipped", "failed", "failed"]
    assert all(reruns[n]["ate_rmse_m"] == runs[n]["ate_rmse_m"] for n in GOOD)
    assert stamps == {n: (out / n / "summary.json").stat().st_mtime_ns for n in GOOD}, "a complete run was redone"


@pytest.mark.e2e
@pytest.mark.skipif(importlib.util.find_spec("ray") is None,
                    reason="ray is not installed (pip install -e \".[ray]\"; the dev extra has it)")
def test_ray_gives_the_same_summary_as_the_pool(dataset, tmp_path):
    pool, ray = tmp_path / "pool", tmp_path / "ray"
    assert _batch(str(dataset), "--out", str(pool), "--workers", "1").returncode == 2
    r = _batch(str(dataset), "--out", str(ray), "--workers", "1", "--ray", "local")
    assert r.returncode == 2, r.stderr[-2000:]
    a, b = _runs(pool), _runs(ray)
    assert list(a) == list(b)
    for name in a:
        assert {k: a[name][k] for k in SAME} == {k: b[name][k] for k in SAME}, name
        if name in GOOD:
            assert b[name]["ate_rmse_m"] == pytest.approx(a[name]["ate_rmse_m"], rel=1e-6)
    assert json.loads((ray / "batch.json").read_text())["settings"]["ray"] == "local"


class _FlakyExecutor:
    """Runs jobs in the test's process: the first attempt at ``flaky`` fails, as a dead worker does."""

    slots = 2

    def __init__(self, flaky: str) -> None:
        self.flaky, self.calls = flaky, []

    def submit(self, job: Job) -> Future:
        self.calls.append(job.item.name)
        f: Future = Future()
        if job.item.name == self.flaky and self.calls.count(self.flaky) == 1:
            f.set_exception(RuntimeError("worker died\nwith a traceback"))
        elif job.item.name == "bad":
            f.set_result(Row(job.item.name, "", str(job.out), error="bad: broken"))
        else:
            f.set_result(Row(job.item.name, "", str(job.out), status="ok"))
        return f

    def close(self) -> None:
        pass


def test_loop_retries_a_failed_run_once(tmp_path):
    jobs = [Job(BatchItem(n, tmp_path / n), tmp_path / "out" / n, None, None) for n in ("a", "flaky", "bad")]
    executor = _FlakyExecutor("flaky")
    rows = BatchLoop(jobs, executor, progress=False).run()
    assert [(r.name, r.status, r.attempts) for r in rows] == [("a", "ok", 1), ("flaky", "ok", 2), ("bad", "failed", 2)]
    assert sorted(executor.calls) == ["a", "bad", "bad", "flaky", "flaky"]


def test_budget_fills_the_machine():
    assert budget(None, None, machine=16) == budget(8, None, machine=16) == budget(None, 1, machine=16)
    assert (budget(None, None, machine=16).workers, budget(None, None, machine=16).threads) == (8, 1)
    assert budget(2, None, machine=16).threads == 7 and budget(2, None, machine=16).cores == 8
    assert budget(None, 3, machine=16).workers == 4 and budget(None, None, machine=1).workers == 1
    assert budget(2, None, machine=2) == budget(2, 1, machine=2) and budget(2, None, machine=2).cores == 1
    with pytest.raises(InputError, match="--workers must be >= 1"):
        budget(0, None)


def test_dataset_folder_names_each_sequence_once(tmp_path):
    for name in ("b", "a", ".hidden"):
        (tmp_path / name).mkdir()
    (tmp_path / "a.mp4").write_bytes(b"")
    (tmp_path / "notes.txt").write_text("not a sequence")
    assert [(i.name, i.source.name) for i in find_items(tmp_path)] == [("a", "a"), ("a_2", "a.mp4"), ("b", "b")]
    with pytest.raises(InputError, match="no such folder or list file"):
        find_items(tmp_path / "nothing")
    (tmp_path / "empty.txt").write_text("# nothing\n")
    with pytest.raises(InputError, match="names none"):
        find_items(tmp_path / "empty.txt")


def test_batch_help_imports_no_heavy_library():
    loaded = packages_loaded_by("c3f_slam", "batch", "--help")
    assert not loaded & {"numpy", "cv2", "open3d", "onnxruntime", "scipy", "torch", "ray"}, sorted(loaded)
