"""Protocols: fixed measurements, rerun to update a recorded result (``python -m benchmarks.protocols.NAME``).

Each writes its Markdown report and, beside it, the same numbers as JSON (``results/NAME.md`` and
``results/NAME.json``), and runs with no path given: its sequences are regenerated from seeds under
``runs/bench/NAME`` (``--work``), its models are named (the zoo) or trained by the protocol itself.
"""
