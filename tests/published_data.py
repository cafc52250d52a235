"""Tiny simulated sequences in the published data sets' layouts, with cameras that match what
each loader assumes when it is given no option (so the default reading path is the one tested)."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

from datamodules.formats import uts as uts_format
from datamodules.formats.omnicam import C3VD_CALIBRATION
from datamodules.synthetic import generate_sequence, tiny_params

#: horizontal field of view of UTS's physical camera (4.969783 mm on a 10.26 mm wide sensor)
UTS_FOV = 2 * math.degrees(math.atan(uts_format.SENSOR_WIDTH_MM / 2 / uts_format.FOCAL_MM))
C3VD_SCALE = 0.1  # 135 x 108 frames: C3VD's 1350 x 1080 scaled
#: the pinhole that C3VD frames undistort to by default has f = a0 (scaled): this field of view
C3VD_FOV = 2 * math.degrees(math.atan(135 / 2 / (C3VD_CALIBRATION.a0 * C3VD_SCALE)))

#: each layout's frame size (pixels, N or WxH) and other camera fields (``tiny_params`` keywords)
CAMERAS = {
    "uts": {"size": "64x48", "camera.fov": UTS_FOV},
    "simcol3d": {"size": 48},
    "c3vd": {"size": "135x108", "camera.fov": C3VD_FOV},
    "colon10k": {"size": "270x216"},
}
#: where each layout's sequence lands inside OUT/<layout>/
SEQUENCE_DIR = {"uts": "Case0001", "simcol3d": "SyntheticColon_C3F/Frames_S1", "c3vd": "c3f_sim",
                "colon10k": "c3f_sim"}
FRAMES = 5


def make_published(out: Path, layout: str) -> tuple[Path, Path]:
    params = tiny_params(frames=FRAMES, seed=3, **CAMERAS[layout])
    generate_sequence(params, out, progress=False, layout=layout)
    return out, out / layout


def copy_layout(root: Path, dst: Path) -> Path:
    """A writable copy of a layout folder (for tests that damage files)."""
    shutil.copytree(root, dst)
    return dst
