"""c3f_slam: the torch-free core and SLAM runtime of C3Fusion (it never imports torch).

- shared by every package: ``camera`` (pinhole model), ``geometry`` (rigid-body maths in
  NumPy; poses camera-to-world, metres), ``io`` (the project's sequence layout, TUM
  trajectories, atomic writes), ``errors`` (``InputError``: bad user input, one line);
- the runtime's parts: ``stream`` (frames of a folder or video), ``preprocess``, ``models``
  (ONNX files and their metadata), ``matching`` (SIFT, matching, the match filter),
  ``posegraph`` (pose graphs with line-process pruning), ``frustum``, ``fusion`` (TSDF),
  ``outputs`` (the run folder's files);
- ``pipeline``: the SLAM run itself (settings, sources, back-ends, run loop, evaluation);
- measuring a run: ``trajectory_metrics`` (ATE, RPE, frame motion), ``trajectory_plot``,
  ``depth_metrics`` (the seven depth metrics, median scaling; NumPy or torch tensors),
  ``surface_metrics`` (coverage of the true surface);
- ``cli``: ``python -m c3f_slam run | evaluate | inspect``.
"""

__version__ = "0.1.0"
