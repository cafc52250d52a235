"""PNG of an estimated trajectory against the ground truth (top and side view).

Positions are world coordinates in metres (plotted in cm).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from c3f_core.atomic import atomic_write


def plot_trajectories(path: str | Path, gt_positions: np.ndarray, est_positions: np.ndarray | None = None,
                      title: str = "") -> None:
    """Write a PNG with a top view (x vs z) and a side view (z vs -y) of the trajectories.

    Positions are (N, 3) world coordinates in metres (plotted in cm); the world frame is
    the first camera's (x right, y down, z forward), so "up" in the side view is -y.
    Give the estimate already aligned (``ATEResult.aligned[:, :3, 3]``).
    """
    from matplotlib.figure import Figure  # no pyplot: renders with Agg, no display needed

    fig = Figure(figsize=(10, 4.5), dpi=100)
    views = (("top view", 0, 2, 1.0, "x [cm]", "z [cm]"), ("side view", 2, 1, -1.0, "z [cm]", "-y (up) [cm]"))
    for k, (name, a, b, sb, la, lb) in enumerate(views):
        ax = fig.add_subplot(1, 2, k + 1)
        for pos, label, style in ((gt_positions, "ground truth", "k-"), (est_positions, "estimate", "r-")):
            if pos is None or len(pos) == 0:
                continue
            p = np.asarray(pos) * 100.0
            ax.plot(p[:, a], sb * p[:, b], style, lw=1.2, label=label)
            ax.plot(p[0, a], sb * p[0, b], style[0] + "o", ms=4)
        ax.set_title(name)
        ax.set_xlabel(la)
        ax.set_ylabel(lb)
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(True, lw=0.3)
        ax.legend(loc="best", fontsize=8)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    with atomic_write(Path(path), suffix=".png") as tmp:
        fig.savefig(tmp, format="png")
