"""One sequence of a batch: the run (:func:`c3f_slam.pipeline.run_slam`, the function ``run``
calls), then its evaluation where the sequence has ground truth, as one row of the summary.

:func:`run_job` is what a worker executes, in a pool process or a Ray task: it never raises,
a failure is a row with status ``failed`` and the error's one line. :func:`finished_row` reads
the row of a run folder that an earlier batch completed (summary.json status ``ok``), so a
rerun skips it. Heavy libraries are imported inside the functions: a pool process limits its
threads (:func:`limit_threads`) before NumPy and OpenCV load.
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from c3f_core.errors import InputError
from c3f_slam.batch.dataset import BatchItem

#: the thread pools of the numerical libraries, limited in each worker process
THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
STATUSES = ("ok", "skipped", "failed")  #: ok: run now; skipped: complete from an earlier batch


@dataclass(frozen=True)
class Job:
    """One run of a batch: the sequence, its run folder, and the settings of ``run``.

    ``cfg`` is the settings tree (:class:`c3f_slam.config.SlamConfig`), ``inputs`` the
    :class:`c3f_slam.pipeline.RunInputs` (models, ``threads``: onnxruntime threads per model);
    ``cores``: the worker's thread budget (BLAS, OpenCV)."""

    item: BatchItem
    out: Path
    cfg: Any
    inputs: Any
    cores: int = 1
    overwrite: bool = False


@dataclass
class Row:
    """One sequence's line of the batch summary (lengths in metres, times in seconds)."""

    name: str
    sequence: str
    run: str
    status: str = "failed"
    error: str | None = None
    frames: int | None = None
    registered_frames: int | None = None
    registered_share: float | None = None
    ate_rmse_m: float | None = None  #: ATE after Sim(3) alignment, where the sequence has poses.txt
    evaluation_error: str | None = None
    unseen_share: float | None = None
    seconds: float | None = None  #: the run's wall time (summary.json wall_seconds)
    attempts: int = 0

    def as_dict(self) -> dict:
        return asdict(self)


def limit_threads(cores: int) -> None:
    """Cap the numerical libraries' thread pools of this process at ``cores`` (environment
    variables for those not loaded yet; threadpoolctl and OpenCV for the loaded ones)."""
    for name in THREAD_VARIABLES:
        os.environ[name] = str(cores)
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=cores)
    import cv2

    cv2.setNumThreads(cores)


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    return text if isinstance(exc, InputError) else f"{type(exc).__name__}: {text}".rstrip(": ")


def _evaluation(row: Row, run: Path, source: Path) -> None:
    """ATE of the run against ``source``'s poses.txt (``c3f_slam evaluate``'s code, which also
    writes evaluation.json and its figures into the run folder); nothing without poses.txt."""
    if not (source.is_dir() and (source / "poses.txt").is_file()):
        return
    from c3f_slam.pipeline.run_evaluation import evaluate_run

    try:
        res = evaluate_run(run, source)
    except Exception as exc:  # noqa: BLE001 -- the run stands; its row says why it has no ATE
        row.evaluation_error = _one_line(exc)
        return
    if "error" in res:
        row.evaluation_error = str(res["error"])
    else:
        row.ate_rmse_m = float(res["ate_sim3"]["rmse_m"])


def _from_summary(row: Row, summary: dict) -> None:
    row.frames = summary.get("frames")
    row.registered_frames = summary.get("registered_frames")
    row.registered_share = summary.get("registered_share")
    row.unseen_share = summary.get("unseen_share")
    row.seconds = summary.get("wall_seconds")


def _new_row(job: Job) -> Row:
    return Row(job.item.name, str(job.item.source), str(job.out))


def run_job(job: Job) -> Row:
    """Run and evaluate one sequence (in a worker); a failure is the row's status and error."""
    from c3f_slam.pipeline import run_slam

    row, t0 = _new_row(job), time.perf_counter()
    try:
        limit_threads(job.cores)
        summary = run_slam(job.item.source, job.out, job.cfg, job.inputs, progress=False, overwrite=job.overwrite)
    except BaseException as exc:  # noqa: BLE001 -- one sequence's failure never stops the batch
        if isinstance(exc, KeyboardInterrupt):
            raise
        row.error = _one_line(exc)
        row.seconds = time.perf_counter() - t0
        return row
    row.status = "ok"
    _from_summary(row, summary)
    _evaluation(row, job.out, job.item.source)
    return row


def finished_row(job: Job) -> Row | None:
    """The row of a run folder that an earlier batch completed (summary.json status ``ok``),
    its ATE read back from its evaluation.json; None when the run is still to be made."""
    try:
        summary = json.loads((job.out / "summary.json").read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(summary, dict) or summary.get("status") != "ok":
        return None
    row = _new_row(job)
    row.status = "skipped"
    _from_summary(row, summary)
    try:
        res = json.loads((job.out / "evaluation.json").read_text())
        row.ate_rmse_m = res["ate_sim3"]["rmse_m"]
    except (OSError, ValueError, KeyError, TypeError):
        if job.item.source.is_dir() and (job.item.source / "poses.txt").is_file():
            _evaluation(row, job.out, job.item.source)  # complete, but the earlier batch stopped before this
    return row


__all__ = ["STATUSES", "THREAD_VARIABLES", "Job", "Row", "finished_row", "limit_threads", "run_job"]
