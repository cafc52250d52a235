"""Readers of the published data sets, torch-free (used by the data modules and the converter).

=============  ======================================  ==========================
name           data set                                ground truth
=============  ======================================  ==========================
``uts``        UTS-synthetic (:mod:`.uts`)             depth (simulator output), poses
``simcol3d``   SimCol3D (:mod:`.simcol3d`)             depth, poses, train/test split
``c3vd``       C3VD print data (:mod:`.c3vd`)          depth, poses, mesh, coverage
``colon10k``   Colon10K (:mod:`.colon10k`)             none
``c3f``        the project's layout (:mod:`.project`)  what the folder holds
=============  ======================================  ==========================

``make_format(name, **options)`` builds one; :func:`find_sequences` lists the sequences under
a folder (the data set as published, or any folder above whole sequences) and says what was
expected when there are none. Each module's docstring states the conventions it chose.
"""

from __future__ import annotations

import inspect
from pathlib import Path

from c3f_core.errors import InputError
from datamodules.formats.base import PublishedSequence, SequenceFormat
from datamodules.formats.c3vd import C3VDFormat
from datamodules.formats.colon10k import Colon10KFormat
from datamodules.formats.project import ProjectFormat
from datamodules.formats.simcol3d import SimCol3DFormat
from datamodules.formats.uts import UTSFormat

FORMATS: dict[str, type[SequenceFormat]] = {
    f.name: f for f in (UTSFormat, SimCol3DFormat, C3VDFormat, Colon10KFormat, ProjectFormat)
}
PUBLISHED = ("uts", "simcol3d", "c3vd", "colon10k")

__all__ = ["FORMATS", "PUBLISHED", "PublishedSequence", "SequenceFormat", "find_sequences", "make_format"]


def make_format(name: str, option_prefix: str = "", **options) -> SequenceFormat:
    """The format ``name`` with its options (``fov`` for uts, ``calibration`` and
    ``pinhole_focal`` for c3vd, ``calibration`` for colon10k, ``min_frames`` for c3f)."""
    cls = FORMATS.get(name)
    if cls is None:
        raise InputError(f"{option_prefix}layout: unknown data set {name!r} (choose from {', '.join(FORMATS)})")
    accepted = [p for p in inspect.signature(cls.__init__).parameters if p != "self"]
    unknown = [k for k in options if k not in accepted]
    if unknown:
        raise InputError(f"{option_prefix}layout_options: {name} does not take {unknown[0]!r} "
                         f"(it takes {', '.join(accepted) or 'no options'})")
    return cls(**options)


def find_sequences(fmt: SequenceFormat, root: str | Path) -> dict[str, Path]:
    """``{name: folder}`` of the sequences under ``root``; InputError naming what was expected
    (and the data set the folder looks like) when there are none, or when two share a name."""
    root = Path(root)
    found = fmt.find(root)
    if not found:
        others = [cls for name, cls in FORMATS.items() if name != fmt.name]
        # find() does not depend on a format's options: probe each without calling its constructor
        looks_like = next((cls for cls in others if cls.__new__(cls).find(root)), None)
        hint = f"; it looks like {looks_like.title} data ({looks_like.name})" if looks_like else ""
        raise InputError(f"{root}: no {fmt.title} sequences found (expected {fmt.layout}){hint}")
    names: dict[str, Path] = {}
    for folder in found:
        name = fmt.sequence_name(folder)
        if name in names:
            raise InputError(f"{root}: two sequences named {name!r} ({names[name]} and {folder})")
        names[name] = folder
    return names
