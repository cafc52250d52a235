"""What a user looks at: the unrolled wall map (PNG) and the mesh with the unseen wall painted (PLY).

The map is the wall cut open along the centreline: distance along it (cm) across, the way
around it (cm of circumference at the mean wall radius, from the angle origin of the
centreline's frame) up. Observed cells show the reconstruction's colour, unseen ones
:data:`UNSEEN_COLOUR`. The painted mesh is the fused mesh plus a patch per unseen wall cell,
placed on the wall model (where the reconstruction has a hole, that is where the wall
should be).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import open3d as o3d

from c3f_core.atomic import atomic_write
from c3f_slam.coverage.estimate import CoverageMap

UNSEEN_COLOUR = (0.05, 0.55, 1.0)  #: bright blue: stands out on pink-orange mucosa
NO_COLOUR = (0.6, 0.6, 0.6)  #: observed cells without a reconstructed colour


def map_image(cov: CoverageMap) -> np.ndarray:
    """(A, S, 3) RGB in [0, 1]: rows = angle, columns = distance along the centreline."""
    col = np.where(np.isfinite(cov.wall.colour), cov.wall.colour, np.array(NO_COLOUR))
    img = np.where(cov.observed[..., None], col, np.array(UNSEEN_COLOUR))
    return np.clip(np.transpose(img, (1, 0, 2)), 0, 1)


def draw_coverage_map(path: str | Path, cov: CoverageMap, segment: float, title: str = "") -> None:
    """Write the unrolled map as a PNG with the per-segment unseen shares above it."""
    from matplotlib.figure import Figure  # no pyplot: Agg, no display needed
    from matplotlib.patches import Patch

    length_cm = 100 * cov.length
    around_cm = 100 * 2 * np.pi * float(np.mean(cov.wall.radius))
    fig = Figure(figsize=(float(np.clip(4 + 0.1 * length_cm, 7.0, 16.0)), 4.2), dpi=100)
    ax = fig.add_subplot(1, 1, 1)
    ax.imshow(map_image(cov), origin="lower", aspect="auto", interpolation="nearest",
              extent=(0, length_cm, 0, around_cm))
    for seg in cov.segments(segment):
        ax.axvline(100 * seg["start_m"], color="k", lw=0.6)
        mid = 50 * (seg["start_m"] + seg["end_m"])
        ax.text(mid, around_cm * 1.01, f"{100 * seg['unseen_share']:.0f} %", ha="center", va="bottom", fontsize=7)
    ax.set_xlim(0, length_cm)
    ax.set_xlabel("along the centreline, from the first camera position [cm]")
    ax.set_ylabel("around the wall [cm]")
    fig.legend(handles=[Patch(color=UNSEEN_COLOUR, label="unseen"), Patch(color=NO_COLOUR, label="seen, no colour")],
               loc="upper right", fontsize=8, frameon=False, ncols=2)
    ax.set_title(title or f"unseen {100 * cov.unseen_share():.1f} % of the wall "
                          f"(per {segment * 100:g} cm segment above the map)", fontsize=9, pad=14, loc="left")
    fig.tight_layout()
    with atomic_write(Path(path), suffix=".png") as tmp:
        fig.savefig(tmp, format="png")


def unseen_patches(cov: CoverageMap) -> o3d.geometry.TriangleMesh:
    """One quad (two triangles) per unseen cell on the wall model, painted :data:`UNSEEN_COLOUR`."""
    wall = cov.wall
    i, j = np.nonzero(~cov.observed)
    ds, dt = wall.cell_length / 2, wall.cell_angle / 2
    s, th = wall.s_centres[i], wall.theta_centres[j]
    r = wall.radius[i, j]
    corners = [wall.centreline.wall_points(s + a * ds, th + b * dt, r) for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    V = np.stack(corners, axis=1).reshape(-1, 3)
    q = 4 * np.arange(len(i))[:, None]
    F = np.concatenate([q + [0, 1, 2], q + [0, 2, 3]])
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(F))
    mesh.vertex_colors = o3d.utility.Vector3dVector(np.tile(UNSEEN_COLOUR, (len(V), 1)))
    return mesh


def unseen_mesh(mesh: o3d.geometry.TriangleMesh, cov: CoverageMap) -> o3d.geometry.TriangleMesh:
    """The reconstruction with the unseen wall patches added (uncoloured vertices grey)."""
    out = o3d.geometry.TriangleMesh(mesh)
    if not out.has_vertex_colors():
        out.vertex_colors = o3d.utility.Vector3dVector(np.tile(NO_COLOUR, (len(out.vertices), 1)))
    return out + unseen_patches(cov)
