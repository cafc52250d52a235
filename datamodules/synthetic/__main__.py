"""Command line of the simulator.

    python -m datamodules.synthetic generate --preset seq1 --set seed=7 --set path.frames=300 \\
        --set camera.width=256 --set camera.height=256 --out DIR
    python -m datamodules.synthetic generate --out DIR --set colon.length=0.5 --set camera.fov=120 \\
        --set path.kind=B --set path.loop=true --set colon.fold_height=0.45 --set appearance.wetness=0.5
    python -m datamodules.synthetic generate --config OLD/params.json --out NEW   # replays OLD
    python -m datamodules.synthetic generate --preset seq1 --print-config > sim.yaml  # every parameter
    python -m datamodules.synthetic contact-sheet DIR --out sheet.png
    python -m datamodules.synthetic presets

The parameters are set like every command's settings (:mod:`c3f_core.settings_cli`): the preset,
then ``--config`` (YAML / JSON as ``--print-config`` writes it, or a sequence's params.json),
then each ``--set part.field=value``. Bad options print one line ``error: ...`` and exit with
status 2 before anything is written; the former flags (``--frames``, ``--size``, ...) say what
replaces them (:data:`REMOVED`).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import Any

from c3f_core.cli_parser import OneLineParser
from c3f_core.errors import InputError
from c3f_core.settings_cli import add_settings_options


def _sets(*items: str) -> str:
    return " ".join(f"--set {item}" for item in items)


#: the former parameter flags of ``generate``: flag -> (does it take a value, what replaces it)
REMOVED: dict[str, tuple[bool, str]] = {
    "--seed": (True, _sets("seed=N")),
    "--frames": (True, _sets("path.frames=N")),
    "--size": (True, _sets("camera.width=N", "camera.height=N")),
    "--length": (True, _sets("colon.length=M")),
    "--radius": (True, _sets("colon.radius=M")),
    "--fov": (True, _sets("camera.fov=DEG")),
    "--path": (True, _sets("path.kind=KIND")),
    "--loop": (False, _sets("path.loop=true")),
    "--params": (True, "--config FILE"),
}


def removed_message(flag: str) -> str:
    """The one line for the removed flag ``flag`` (a key of :data:`REMOVED`)."""
    return f"{flag} was removed: use {REMOVED[flag][1]}"


class _Removed(argparse.Action):
    """A removed flag (hidden from ``--help``): one ``error:`` line naming its replacement, exit status 2."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        parser.error(removed_message(self.option_strings[0]))


def _parser() -> argparse.ArgumentParser:
    from datamodules.synthetic.params import SIM_SETTINGS

    ap = OneLineParser(prog="python -m datamodules.synthetic", description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="command", required=True)

    g = sub.add_parser("generate", help="simulate a sequence into a folder")
    g.add_argument("--out", help="output folder (must not exist or be empty, unless --overwrite); "
                                 "required unless --print-config")
    g.add_argument("--layout", default="c3f",
                   help="c3f (default); also write uts, simcol3d, c3vd or colon10k beside it")
    g.add_argument("--overwrite", action="store_true", help="replace a non-empty output folder")
    g.add_argument("--no-progress", action="store_true", help="no progress bar")
    g.add_argument("--contact-sheet", metavar="PNG", help="also write a contact sheet of the result")
    add_settings_options(g, SIM_SETTINGS, example="path.frames=300 --set camera.width=256 --set camera.height=256",
                         replay="a sequence's params.json")
    for flag, (takes_value, _) in REMOVED.items():
        g.add_argument(flag, action=_Removed, nargs="?" if takes_value else 0, dest=argparse.SUPPRESS,
                       default=argparse.SUPPRESS, help=argparse.SUPPRESS)

    c = sub.add_parser("contact-sheet", help="grid of frames (RGB over depth) of a sequence")
    c.add_argument("seq", help="sequence folder")
    c.add_argument("--out", required=True, help="PNG to write")
    c.add_argument("--count", type=int, default=12)
    c.add_argument("--cols", type=int, default=4)
    c.add_argument("--tile", type=int, default=256, help="tile width, pixels")
    c.add_argument("--no-depth", action="store_true")

    sub.add_parser("presets", help="list the presets and their parameters")
    return ap


def _generate(args: argparse.Namespace) -> int:
    from datamodules.synthetic.params import SIM_SETTINGS, check_layout, check_output

    if not args.out and not args.print_config:
        raise InputError("--out: the output folder is required (unless --print-config)")
    params = SIM_SETTINGS.from_args(args)
    if args.print_config:
        print(SIM_SETTINGS.yaml(params), end="")
        return 0
    check_layout(args.layout)
    check_output(args.out, args.overwrite)
    from datamodules.synthetic.generate import generate_sequence  # heavy imports only now

    out = generate_sequence(params, args.out, overwrite=args.overwrite, progress=not args.no_progress,
                            layout=args.layout)
    print(f"wrote {params.path.frames} frames to {out}")
    if args.contact_sheet:
        from datamodules.synthetic.contact_sheet import make_contact_sheet

        print(f"contact sheet: {make_contact_sheet(out, args.contact_sheet)}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        if args.command == "generate":
            return _generate(args)
        if args.command == "contact-sheet":
            from datamodules.synthetic.contact_sheet import make_contact_sheet

            out = make_contact_sheet(args.seq, args.out, count=args.count, cols=args.cols,
                                     depth=not args.no_depth, tile=args.tile)
            print(f"contact sheet: {out}")
        elif args.command == "presets":
            from datamodules.synthetic.params import PRESETS, get_preset

            for name in PRESETS:
                p = get_preset(name)
                a, path = p.appearance, p.path
                print(f"{name:8s} seed={p.seed} path={path.kind} frames={path.frames}"
                      f" size={p.camera.width}x{p.camera.height}"
                      f" fov={p.camera.fov:g} hue={a.hue:.2f} sat={a.saturation:.3f} val={a.value:.3f}"
                      f" wet={a.wetness:.2f} vessels={a.vessel_size:.2f}/{a.vessel_opacity:.2f}"
                      f" light={a.light_angle:g}deg/{a.light_intensity:.2f} grain={a.grain:g}")
            print("every parameter of a preset: generate --preset NAME --print-config")
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        what = "no contact sheet" if args.command == "contact-sheet" else "no sequence"
        print(f"error: interrupted; {what} was written", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
