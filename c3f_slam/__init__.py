"""c3f_slam: the torch-free core and SLAM runtime of C3Fusion.

This package never imports torch. It holds the pieces every other package reuses:
the pinhole camera model (`camera`), rigid-body geometry in NumPy (`geometry`), and the
project's sequence layout and TUM trajectory I/O (`io`).
"""

__version__ = "0.1.0"
