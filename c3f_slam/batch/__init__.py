"""``python -m c3f_slam batch``: a data set reconstructed in one command
(docs/runtime.md, Batch: many sequences in one command).

- :mod:`.dataset`: the sequences of a folder or a list file, each with its run folder's name;
- :mod:`.job`: one sequence's run (:func:`c3f_slam.pipeline.run_slam`, as ``run``) and
  evaluation, as a row of the summary;
- :mod:`.executors`: where the runs execute: local worker processes, or Ray tasks;
- :mod:`.scheduler`: skip the complete runs, retry a failed one once, progress over sequences;
- :mod:`.report`: batch.json, batch.csv, index.html;
- :mod:`.cli`: the subcommand's options and what it does.

Nothing here is imported by ``python -m c3f_slam --help`` but :mod:`.cli`, which loads no
heavy library until a batch runs.
"""
