"""The runtime's command line: ``python -m c3f_slam run | batch | evaluate | inspect | view | calibrate | simcol3d``.

``main`` (the parser and the sub-commands), ``inputs`` (a run's inputs from the options),
``settings_options`` (``--preset/--config/--set/--print-config`` and the removed flags).
"""
