"""Studies: one-off investigations (``python -m benchmarks.studies.NAME``); their findings are written
by hand around the generated tables, and their inputs are given on the command line."""
