"""Benchmark scripts (outside CI) and their recorded results in ``benchmarks/results/``.

Run a script from the repository root as a module, e.g. ``python -m benchmarks.slam_ate --help``
(see ``benchmarks/README.md``); what they share is in :mod:`benchmarks.common`.
"""
