"""Where a batch's runs execute: a pool of local worker processes, or Ray tasks.

Both give :class:`concurrent.futures.Future` objects of :func:`c3f_slam.batch.job.run_job`'s
rows, so the scheduler (:mod:`c3f_slam.batch.scheduler`) is one code path for both.

- :class:`PoolExecutor`: ``workers`` processes (started fresh, "spawn": nothing of the parent's
  libraries is inherited), each with its numerical libraries capped at ``cores`` threads. A
  worker that dies (a crash in a native library) breaks the pool: the runs in flight fail with
  that error, and the next submission starts a new pool.
- :class:`RayExecutor`: one Ray task per run, asking Ray for ``cores`` CPUs, on the cluster at
  ``address`` (``auto``: the one this machine belongs to, as ``ray start`` made it; ``local``: a
  Ray instance started here for this batch with ``workers x cores`` CPUs). Every node needs
  this project installed and the data set and output folder at the same paths (shared storage).
"""

from __future__ import annotations

import logging
import multiprocessing
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import Protocol

from c3f_core.errors import InputError
from c3f_slam.batch.job import Job, limit_threads, run_job

LOCAL = "local"  #: ``--ray local``: start a Ray instance on this machine


class Executor(Protocol):
    """What the scheduler needs: submit a job, how many to keep in flight, close."""

    slots: int

    def submit(self, job: Job) -> Future: ...

    def close(self) -> None: ...


@dataclass
class PoolExecutor:
    """``workers`` local processes with ``cores`` threads each."""

    workers: int
    cores: int
    _pool: ProcessPoolExecutor | None = None

    @property
    def slots(self) -> int:
        return self.workers

    def _new_pool(self) -> ProcessPoolExecutor:
        return ProcessPoolExecutor(self.workers, mp_context=multiprocessing.get_context("spawn"),
                                   initializer=limit_threads, initargs=(self.cores,))

    def submit(self, job: Job) -> Future:
        if self._pool is None:
            self._pool = self._new_pool()
        try:
            return self._pool.submit(run_job, job)
        except BrokenProcessPool:  # a worker died: the runs in flight failed with it; go on with a new pool
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = self._new_pool()
            return self._pool.submit(run_job, job)

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None


class RayExecutor:
    """Ray tasks of ``cores`` CPUs each on the cluster at ``address`` (or ``local``)."""

    def __init__(self, address: str, workers: int | None, cores: int) -> None:
        try:
            import ray
        except ImportError:
            raise InputError("--ray needs Ray: pip install -e \".[ray]\" (or pip install ray)") from None
        self._ray = ray
        if address == LOCAL:
            ray.init(num_cpus=(workers or 1) * cores, include_dashboard=False, log_to_driver=False,
                     logging_level=logging.ERROR)
        else:
            try:
                ray.init(address=address, log_to_driver=False)
            except (ConnectionError, ValueError, RuntimeError) as exc:
                raise InputError(f"--ray {address}: no Ray cluster there ({str(exc).strip().splitlines()[0]})") \
                    from None
        self._task = ray.remote(num_cpus=cores, max_retries=0)(run_job)
        cpus = int(ray.cluster_resources().get("CPU", cores))
        #: in flight at once: what the cluster runs together (``--workers`` caps it)
        self.slots = max(1, min(workers or cpus // cores, cpus // cores))

    def submit(self, job: Job) -> Future:
        return self._task.remote(job).future()

    def close(self) -> None:
        self._ray.shutdown()


def make_executor(workers: int, cores: int, ray: str | None, workers_given: bool = True) -> Executor:
    """A :class:`RayExecutor` for ``ray`` (``local``, ``auto`` or an address), else a :class:`PoolExecutor`."""
    if ray:
        return RayExecutor(ray, workers if workers_given or ray == LOCAL else None, cores)
    return PoolExecutor(workers, cores)


__all__ = ["LOCAL", "Executor", "PoolExecutor", "RayExecutor", "make_executor"]
