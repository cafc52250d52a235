"""``python -m c3f_slam batch DATASET --out OUT``: every sequence of a data set reconstructed
into OUT/NAME/ (one run folder each, as ``run`` writes it), then OUT/batch.json, batch.csv and
index.html (:mod:`c3f_slam.batch.report`); batch.json's ``config`` is the settings tree of the
runs, which ``batch --config OUT/batch.json`` replays.

The options of ``run`` that choose the inputs, models and settings (``--preset``, ``--config``,
``--set``, ``--depth-model``, ...) apply to every sequence. Locally ``--workers`` processes run
at once, each with an equal share of the cores (:func:`budget`); ``--ray`` runs the same jobs as
Ray tasks of that many CPUs. A rerun skips the complete runs; a
sequence whose run fails is tried once more, then reported; the command ends with exit status
2 and one ``error:`` line naming the failed sequences when any failed.
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import dataclass
from pathlib import Path

from c3f_core.errors import InputError
from c3f_slam.cli.inputs import add_input_options, inputs_from_args, settings_from_args
from c3f_slam.cli.settings_options import add_settings_options

THREADS_HELP = ("onnxruntime threads per model in each worker (default: the worker's share of the cores less one, "
                "at least 1)")
SHOWN_FAILURES = 5  #: failed sequences named in the final error line (all are in the summary)


def add_batch_parser(sub: argparse._SubParsersAction) -> None:
    """The ``batch`` subcommand's parser."""
    b = sub.add_parser("batch", help="run SLAM on every sequence of a data set (a folder or a list file) into one "
                                     "folder of run folders, with a summary (CSV, JSON, HTML)",
                       description="Run SLAM on every sequence of a data set, in parallel worker processes (or Ray "
                                   "tasks), each into OUT/NAME as `run` writes it; a rerun skips complete runs.")
    b.add_argument("dataset", nargs="?", help="a folder of sequence folders and/or videos, or a list file (one "
                                              "sequence folder or video per line, relative to the file; # comments)")
    b.add_argument("--out", help="output folder: OUT/NAME/ per sequence, OUT/index.html, batch.json, batch.csv")
    b.add_argument("--workers", type=int, help="runs at once, each with an equal share of the cores (default: the "
                                               "cores / (--threads + 1), at least 1); with --ray: at most this many")
    b.add_argument("--ray", metavar="ADDRESS", help="run on Ray: auto (the cluster this machine is in), a cluster's "
                                                    "address, or local (a Ray instance started here); needs the "
                                                    "project's ray extra, and the same paths on every node")
    add_input_options(b, THREADS_HELP)
    b.add_argument("--overwrite", action="store_true", help="run again the sequences whose run is complete")
    b.add_argument("--quiet", action="store_true", help="no progress bar")
    add_settings_options(b)


@dataclass(frozen=True)
class Budget:
    """Runs at once and, per run, onnxruntime threads per model and cores (BLAS, OpenCV)."""

    workers: int
    threads: int
    cores: int


def budget(workers: int | None, threads: int | None, machine: int | None = None) -> Budget:
    """Fill the machine (``machine`` cores, default all): ``workers`` runs (default: as many as
    runs of ``threads + 1`` cores fit), each with an equal share of the cores (its numerical
    libraries' threads) and ``threads`` onnxruntime threads per model (default: its share less
    one for the back-end, at least 1)."""
    machine = machine or os.cpu_count() or 1
    if workers is not None and workers < 1:
        raise InputError(f"--workers must be >= 1, got {workers}")
    if threads is not None and threads < 1:
        raise InputError(f"--threads must be >= 1, got {threads}")
    if workers is None:
        workers = max(1, machine // ((threads or 1) + 1))
    cores = max(1, machine // workers)
    return Budget(workers, threads or max(1, cores - 1), cores)


def _settings_record(args: argparse.Namespace, b: Budget) -> dict:
    keys = ("dataset", "out", "ray", "preset", "config", "set", "depth_source", "descriptors", "depth_model",
            "feature_model", "providers")
    return {**{k: getattr(args, k) for k in keys}, "workers": b.workers, "threads": b.threads, "cores": b.cores}


def _failure_line(rows: list, out: Path) -> str:
    failed = [r for r in rows if r.status == "failed"]
    named = "; ".join(f"{r.name} ({r.error})" for r in failed[:SHOWN_FAILURES])
    more = f"; {len(failed) - SHOWN_FAILURES} more" if len(failed) > SHOWN_FAILURES else ""
    return f"{len(failed)} of {len(rows)} sequences failed: {named}{more} (see {out / 'index.html'})"


def batch_command(args: argparse.Namespace) -> int:
    """Run the batch the options describe; 0 when every sequence has a complete run."""
    from c3f_slam.config.loading import config_yaml

    cfg, _ = settings_from_args(args)
    if args.print_config:
        print(config_yaml(cfg), end="")
        return 0
    missing = [name for name, v in (("dataset", args.dataset), ("--out", args.out)) if v is None]
    if missing:
        raise InputError(f"batch: the following arguments are required: {', '.join(missing)}")
    from c3f_slam.batch.dataset import find_items
    from c3f_slam.batch.executors import make_executor
    from c3f_slam.batch.job import Job
    from c3f_slam.batch.report import counts, write_summary
    from c3f_slam.batch.scheduler import BatchLoop

    b = budget(args.workers, args.threads)
    inputs, out = inputs_from_args(args, b.threads), Path(args.out)
    jobs = [Job(item, out / item.name, cfg, inputs, b.cores, args.overwrite) for item in find_items(args.dataset)]
    out.mkdir(parents=True, exist_ok=True)
    t0, loop, complete = time.perf_counter(), None, False
    executor = make_executor(b.workers, b.cores, args.ray, args.workers is not None)
    try:
        loop = BatchLoop(jobs, executor, progress=not args.quiet)
        rows = loop.run()
        complete = True
    finally:
        executor.close()
        if loop is not None:  # also after Ctrl-C: the rows so far
            write_summary(out, loop.ordered(), _settings_record(args, b), time.perf_counter() - t0, complete,
                          cfg.as_dict())
    c = counts(rows)
    print(f"{len(rows)} sequences: {c['ok']} run, {c['skipped']} complete before, {c['failed']} failed "
          f"-> {out / 'index.html'}")
    if c["failed"]:
        raise InputError(_failure_line(rows, out))
    return 0


__all__ = ["Budget", "add_batch_parser", "batch_command", "budget"]
