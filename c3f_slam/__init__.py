"""c3f_slam: the torch-free SLAM runtime of C3Fusion (it never imports torch).

Grouped by job (the shared kernel, ``errors``/``settings``/``atomic``, is :mod:`c3f_core`):

- ``geometry`` (rigid-body maths in NumPy; poses camera-to-world, metres), ``camera``
  (intrinsics, lens models, calibration, frustum), ``io`` (the sequence layout, TUM
  trajectories, the run folder's files, the SimCol3D writer), shared with training;
- ``frames``: the stream of frames, the quality gate, the tissue area, pre-processing;
- ``models`` (ONNX sessions, their metadata, the zoo), ``matching`` (SIFT, matching, the match
  filter), ``posegraph`` (pose graphs with line-process pruning), ``fusion`` (TSDF),
  ``coverage`` (the unseen wall);
- ``config``: the settings tree; ``pipeline``: the SLAM run itself (sources, front-end,
  back-end, run loop, evaluation); ``batch``: many runs; ``view``: the 3D view and videos;
- ``evaluation``: measuring a run (trajectory, depth and surface metrics, plots);
- ``cli``: ``python -m c3f_slam run | batch | evaluate | inspect | view | calibrate | simcol3d``.
"""

__version__ = "0.1.0"
