"""The batch loop: skip the runs an earlier batch completed, keep the executor's slots busy,
retry a failed run once, count every sequence on a progress bar, return one row per sequence.

A run that fails twice is reported (its row: status ``failed`` and the error's one line); it
never stops the others. An executor's own failure (a worker process that died, a Ray task lost
with its node) counts as the run's failure, retried like any other.
"""

from __future__ import annotations

from collections import deque
from concurrent.futures import FIRST_COMPLETED, Future, wait

from c3f_slam.batch.executors import Executor
from c3f_slam.batch.job import Job, Row, finished_row

ATTEMPTS = 2  #: a failed run is tried once more


def _progress(total: int, done: int, enabled: bool):
    if not enabled:
        return None
    from tqdm import tqdm

    return tqdm(total=total, initial=done, unit="seq", desc="batch", dynamic_ncols=True)


def _row_of(future: Future, job: Job) -> Row:
    """The worker's row; an error of the executor itself is a failed row."""
    try:
        return future.result()
    except Exception as exc:  # noqa: BLE001 -- e.g. BrokenProcessPool, a Ray task error
        text = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
        return Row(job.item.name, str(job.item.source), str(job.out),
                   error=f"{type(exc).__name__}: {text}".rstrip(": "))


class BatchLoop:
    """Runs ``jobs`` on ``executor``; :attr:`rows` by sequence name, filled as runs end."""

    def __init__(self, jobs: list[Job], executor: Executor, progress: bool = True) -> None:
        self.jobs, self.executor = jobs, executor
        self.rows: dict[str, Row] = {}
        self.todo: deque[tuple[Job, int]] = deque()
        for job in jobs:
            earlier = None if job.overwrite else finished_row(job)
            if earlier is not None:
                self.rows[job.item.name] = earlier
            else:
                self.todo.append((job, 1))
        self.bar = _progress(len(jobs), len(self.rows), progress)
        self.running: dict[Future, tuple[Job, int]] = {}

    def run(self) -> list[Row]:
        """Every job to its end; the rows in the jobs' order."""
        try:
            while self.todo or self.running:
                while self.todo and len(self.running) < self.executor.slots:
                    job, attempt = self.todo.popleft()
                    self.running[self.executor.submit(job)] = (job, attempt)
                done, _ = wait(list(self.running), return_when=FIRST_COMPLETED)
                for future in done:
                    self._finished(future)
        finally:
            if self.bar is not None:
                self.bar.close()
        return self.ordered()

    def _finished(self, future: Future) -> None:
        job, attempt = self.running.pop(future)
        row = _row_of(future, job)
        row.attempts = attempt
        if row.status == "failed" and attempt < ATTEMPTS:
            self.todo.append((job, attempt + 1))
            return
        self.rows[job.item.name] = row
        if self.bar is not None:
            self.bar.update(1)
            failed = sum(r.status == "failed" for r in self.rows.values())
            self.bar.set_postfix(failed=failed, refresh=False)

    def ordered(self) -> list[Row]:
        """The rows so far, in the jobs' order."""
        return [self.rows[j.item.name] for j in self.jobs if j.item.name in self.rows]


__all__ = ["ATTEMPTS", "BatchLoop"]
