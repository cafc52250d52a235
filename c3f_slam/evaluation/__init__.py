"""Measuring a run against ground truth: ``trajectory`` (ATE, RPE, frame motion, jitter),
``trajectory_plot``, ``depth`` (the seven depth metrics, median scaling; NumPy or torch
tensors), ``surface`` (coverage of the true surface)."""
