"""Benchmark scripts (outside CI) and their recorded results in ``benchmarks/results/``.

Protocols (:mod:`benchmarks.protocols`, fixed measurements rerun to update a result) and studies
(:mod:`benchmarks.studies`, one-off investigations). Run a script from the repository root as a
module, e.g. ``python -m benchmarks.protocols.slam_ate --help`` (see ``benchmarks/README.md``); what
they share is in :mod:`benchmarks.common`.
"""
