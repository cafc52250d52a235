"""LightningDataModules of the published colonoscopy data sets, reading their files as
released (the readers and every convention they chose: :mod:`datamodules.formats`).

=========================  ==========================================  ==================
data module                ``data_dir`` (as published)                 ground truth
=========================  ==========================================  ==================
:class:`UTSDataModule`     the cases ``Case*/`` (or one case)          depth*, poses
:class:`SimCol3DDataModule`  ``SimCol3D/`` with ``misc/`` and           depth, poses
                           ``SyntheticColon_*/`` (or one scene/frames)
:class:`C3VDDataModule`    the registered sequences (or one)           depth, poses, mesh
:class:`Colon10KDataModule`  the sequences ``<seq>/image/``            none
=========================  ==========================================  ==================

(* UTS's public release has no depth maps; sequences rendered with its simulator do.)
Every other argument is :class:`datamodules.base.SequenceDataModule`'s: the groups ``split``
(by sequence), ``sampling`` (frame tuples), ``frames`` (the centre crop and resize of the paper,
docs/design.md, Pre-processing; intrinsics follow; specular masks) and ``loader``.
The crops of the paper are in ``configs/depthnet/<data set>.yaml``.
"""

from __future__ import annotations

from c3f_core.settings import as_config
from datamodules.base import SequenceDataModule
from datamodules.config import SplitConfig
from datamodules.formats import SequenceFormat, make_format

#: Colon10K's split (the paper's): 80/20 by sequence, no validation sequences
COLON10K_SPLIT = SplitConfig(val_fraction=0.0, test_fraction=0.2)


class UTSDataModule(SequenceDataModule):
    """UTS-synthetic (Zhang et al.'s Unity simulator).

    Args:
        data_dir: folder holding ``Case*/`` folders (or one of them).
        fov: horizontal field of view in degrees of frames rendered with another camera than
            the release's (None = the release's physical camera, 4.969783 mm on 10.26 mm).
    """

    def __init__(self, data_dir: str, fov: float | None = None, **kwargs) -> None:
        super().__init__(data_dir, **kwargs)
        self.fov = fov

    def sequence_format(self) -> SequenceFormat:
        return make_format("uts", fov=self.fov)


class SimCol3DDataModule(SequenceDataModule):
    """SimCol3D. Sequences are named ``<scene>_<frames folder>`` (``SyntheticColon_I_Frames_S1``).

    Args:
        data_dir: the release's folder (holding ``misc/`` and ``SyntheticColon_*/``), or any
            folder above ``Frames_*`` folders.
        published_split: with no ``split.train``/``val``/``test`` given, use the release's
            ``misc/train_file.txt`` and ``test_file.txt`` (``split.val_fraction`` of the training
            sequences become validation) when ``data_dir`` has them.
    """

    def __init__(self, data_dir: str, published_split: bool = True, **kwargs) -> None:
        super().__init__(data_dir, **kwargs)
        self.use_published_split = published_split

    def sequence_format(self) -> SequenceFormat:
        return make_format("simcol3d")

    def published_split(self) -> dict[str, list[str]] | None:
        return super().published_split() if self.use_published_split else None


class C3VDDataModule(SequenceDataModule):
    """C3VD (the paper's print data); frames and depth come undistorted to a pinhole camera.

    Args:
        data_dir: folder of registered sequences (or one of them).
        calibration: an omnidirectional calibration file (``key = value``, C3VDv2's
            ``camera_intrinsics.txt`` form) instead of the one beside the data or C3VD's published one.
        pinhole_focal: focal length in pixels of the pinhole camera frames are undistorted to
            (default: the calibration's a0).
    """

    def __init__(self, data_dir: str, calibration: str | None = None, pinhole_focal: float | None = None,
                 **kwargs) -> None:
        super().__init__(data_dir, **kwargs)
        self.calibration, self.pinhole_focal = calibration, pinhole_focal

    def sequence_format(self) -> SequenceFormat:
        return make_format("c3vd", calibration=self.calibration, pinhole_focal=self.pinhole_focal)


class Colon10KDataModule(SequenceDataModule):
    """Colon10K: real frames, no ground truth; the paper's split is 80/20 by sequence.

    Args:
        data_dir: folder of ``<seq>/image/`` sequences.
        calibration: a DSO-style calibration file for frames that are not Colon10K's 270x216.
        split: as the base's, but by default the paper's 80/20 (``val_fraction`` 0).
    """

    def __init__(self, data_dir: str, calibration: str | None = None, split: SplitConfig = COLON10K_SPLIT,
                 **kwargs) -> None:
        split = as_config(split, COLON10K_SPLIT, "data.split")
        super().__init__(data_dir, split=split, **kwargs)
        self.calibration = calibration

    def sequence_format(self) -> SequenceFormat:
        return make_format("colon10k", calibration=self.calibration)
