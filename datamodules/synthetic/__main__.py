"""Command line of the simulator.

    python -m datamodules.synthetic generate --preset seq1 --frames 300 --size 256 --seed 7 --out DIR
    python -m datamodules.synthetic generate --out DIR --length 0.5 --fov 120 --path B --loop \\
        --set colon.fold_height=0.45 --set appearance.wetness=0.5
    python -m datamodules.synthetic generate --preset seq1 --frames 60 --size 128 --seed 3 --out DIR \\
        --set nuisance.border=octagon --set nuisance.overlay=true --set nuisance.motion_blur_share=0.1
    python -m datamodules.synthetic contact-sheet DIR --out sheet.png
    python -m datamodules.synthetic presets

Bad options print one line ``error: ...`` and exit with status 2 before anything is written.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

from c3f_core.cli_parser import OneLineParser
from c3f_core.errors import InputError


def _parser() -> argparse.ArgumentParser:
    ap = OneLineParser(prog="python -m datamodules.synthetic", description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="command", required=True)

    g = sub.add_parser("generate", help="simulate a sequence into a folder")
    g.add_argument("--out", required=True, help="output folder (must not exist or be empty, unless --overwrite)")
    g.add_argument("--preset", default="default", help="default or seq1..seq8 (the paper's sequences)")
    g.add_argument("--params", help="params.json of an earlier run: start from its parameters")
    g.add_argument("--seed", type=int, help="random seed (default: the preset's)")
    g.add_argument("--frames", type=int, help="number of frames")
    g.add_argument("--size", help="frame size N (square) or WxH, pixels")
    g.add_argument("--length", type=float, help="colon length, metres")
    g.add_argument("--radius", type=float, help="mean lumen radius, metres")
    g.add_argument("--fov", type=float, help="horizontal field of view, degrees")
    g.add_argument("--path", help="camera path: A (insertion), B (withdrawal), random / RP")
    g.add_argument("--loop", action="store_true", help="go forward, then back over the same stretch")
    g.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="any parameter, e.g. colon.fold_height=0.4 or appearance.wetness=0.5 (repeatable)")
    g.add_argument("--layout", default="c3f",
                   help="c3f (default); also write uts, simcol3d, c3vd or colon10k beside it")
    g.add_argument("--overwrite", action="store_true", help="replace a non-empty output folder")
    g.add_argument("--no-progress", action="store_true", help="no progress bar")
    g.add_argument("--contact-sheet", metavar="PNG", help="also write a contact sheet of the result")

    c = sub.add_parser("contact-sheet", help="grid of frames (RGB over depth) of a sequence")
    c.add_argument("seq", help="sequence folder")
    c.add_argument("--out", required=True, help="PNG to write")
    c.add_argument("--count", type=int, default=12)
    c.add_argument("--cols", type=int, default=4)
    c.add_argument("--tile", type=int, default=256, help="tile width, pixels")
    c.add_argument("--no-depth", action="store_true")

    sub.add_parser("presets", help="list the presets and their parameters")
    return ap


def _params_from_args(a: argparse.Namespace):
    from datamodules.synthetic.params import SimParams, apply_overrides, get_preset

    if a.params:
        path = Path(a.params)
        if not path.is_file():
            raise InputError(f"params: {path} not found")
        try:
            data = json.loads(path.read_text())
        except json.JSONDecodeError as exc:
            raise InputError(f"params: {path} is not valid JSON ({exc})") from None
        params = SimParams.from_dict(data.get("params", data))
    else:
        params = get_preset(a.preset)
    overrides: dict[str, object] = {}
    for name in ("seed", "frames", "size", "length", "radius", "fov", "path"):
        value = getattr(a, name)
        if value is not None:
            overrides[name] = value
    if a.loop:
        overrides["loop"] = True
    for item in a.set:
        if "=" not in item:
            raise InputError(f"--set: expected KEY=VALUE, got {item!r}")
        key, value = item.split("=", 1)
        overrides[key.strip()] = value.strip()
    params = apply_overrides(params, overrides)
    params.validate()
    return params


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        if args.command == "generate":
            from datamodules.synthetic.params import check_layout, check_output

            params = _params_from_args(args)
            check_layout(args.layout)
            check_output(args.out, args.overwrite)
            from datamodules.synthetic.generate import generate_sequence  # heavy imports only now

            out = generate_sequence(params, args.out, overwrite=args.overwrite, progress=not args.no_progress,
                                    layout=args.layout)
            print(f"wrote {params.path.frames} frames to {out}")
            if args.contact_sheet:
                from datamodules.synthetic.contact_sheet import make_contact_sheet

                print(f"contact sheet: {make_contact_sheet(out, args.contact_sheet)}")
        elif args.command == "contact-sheet":
            from datamodules.synthetic.contact_sheet import make_contact_sheet

            out = make_contact_sheet(args.seq, args.out, count=args.count, cols=args.cols,
                                     depth=not args.no_depth, tile=args.tile)
            print(f"contact sheet: {out}")
        elif args.command == "presets":
            from datamodules.synthetic.params import PRESETS, get_preset

            for name in PRESETS:
                p = get_preset(name)
                a, path = p.appearance, p.path
                print(f"{name:8s} seed={p.seed} path={path.kind} frames={path.frames} size={p.camera.width}"
                      f" fov={p.camera.fov:g} hue={a.hue:.2f} sat={a.saturation:.3f} val={a.value:.3f}"
                      f" wet={a.wetness:.2f} vessels={a.vessel_size:.2f}/{a.vessel_opacity:.2f}"
                      f" light={a.light_angle:g}deg/{a.light_intensity:.2f} grain={a.grain:g}")
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
