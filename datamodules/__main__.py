"""Command line of the data sets.

    python -m datamodules convert {uts,simcol3d,c3vd,colon10k} SRC --out DST [--overwrite]
    python -m datamodules list {uts,simcol3d,c3vd,colon10k} SRC

``convert`` writes every sequence found under SRC in the project's layout (see
:mod:`datamodules.convert`); ``list`` shows what the loader finds (frames, size, intrinsics,
ground truth) without writing anything. Reader options: ``--fov`` (uts), ``--calibration``
(c3vd, colon10k), ``--pinhole-focal`` (c3vd). Bad input prints one line ``error: ...`` and
exits with status 2; Ctrl-C exits with status 130, leaving no half-written sequence.
The simulator has its own command line: ``python -m datamodules.synthetic``.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from c3f_core.cli_parser import OneLineParser
from c3f_core.errors import InputError

DATASETS = ("uts", "simcol3d", "c3vd", "colon10k")
_OPTIONS = {"uts": ("fov",), "simcol3d": (), "c3vd": ("calibration", "pinhole_focal"), "colon10k": ("calibration",)}


def _parser() -> argparse.ArgumentParser:
    ap = OneLineParser(prog="python -m datamodules", description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="command", required=True)
    for name, text in (("convert", "convert a published data set into the project's layout"),
                       ("list", "list the sequences the loader finds")):
        p = sub.add_parser(name, help=text)
        p.add_argument("dataset", choices=DATASETS)
        p.add_argument("src", help="the data set's folder as published, or any folder above whole sequences")
        if name == "convert":
            p.add_argument("--out", required=True, help="output folder; each sequence becomes OUT/<name>/")
            p.add_argument("--overwrite", action="store_true", help="replace sequences that exist in OUT")
            p.add_argument("--no-progress", action="store_true", help="no progress bar")
        p.add_argument("--only", nargs="+", metavar="NAME", help="only these sequences")
        p.add_argument("--fov", type=float,
                       help="uts: horizontal field of view (deg) of frames not from the release's camera")
        p.add_argument("--calibration", help="c3vd: omnidirectional calibration file; colon10k: DSO-style calibration")
        p.add_argument("--pinhole-focal", type=float, help="c3vd: focal length (px) of the undistorted pinhole camera")
    return ap


def _options(a: argparse.Namespace) -> dict:
    given = {k: getattr(a, k) for k in ("fov", "calibration", "pinhole_focal") if getattr(a, k) is not None}
    wrong = [k for k in given if k not in _OPTIONS[a.dataset]]
    if wrong:
        raise InputError(f"--{wrong[0].replace('_', '-')}: not an option of {a.dataset}")
    return given


def _list(a: argparse.Namespace) -> None:
    from datamodules.convert import open_all

    for name, seq in open_all(a.dataset, a.src, a.only, **_options(a)).items():
        c = seq.camera
        has = {"depth": seq.has_depth, "poses": seq.has_poses, "mesh": seq.mesh_path is not None}
        truth = [k for k, v in has.items() if v]
        print(f"{name}: {len(seq)} frames {c.width}x{c.height}, fx {c.fx:.2f} fy {c.fy:.2f} cx {c.cx:.2f} "
              f"cy {c.cy:.2f}; {', '.join(truth) or 'no ground truth'} ({seq.root})")


def main(argv: Sequence[str] | None = None) -> int:
    a = _parser().parse_args(argv)
    try:
        if a.command == "convert":
            from datamodules.convert import convert

            done = convert(a.dataset, a.src, a.out, overwrite=a.overwrite, only=a.only, progress=not a.no_progress,
                           **_options(a))
            print(f"converted {len(done)} sequence(s) into {a.out}")
        else:
            _list(a)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 130 if str(exc).startswith("interrupted") else 2
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
