"""``python -m c3f_models zoo``: list, show, verify and train the zoo's models, and score them on real frames.

    python -m c3f_models zoo list                  # the entries, their kind and headline numbers
    python -m c3f_models zoo show NAME [--json]    # one entry's card (or its machine-readable part)
    python -m c3f_models zoo verify [NAME ...]     # every file's SHA-256 against its card
    python -m c3f_models zoo recipes               # the recipes ``train`` knows
    python -m c3f_models zoo train NAME [--data DIR] [--work DIR] [--max-minutes M] [--quick]
    python -m c3f_models zoo real NAME --phantom DIR [--every N] [--ttt-steps N]   # real-frame numbers

``train`` runs the recipe (:mod:`c3f_models.zoo.train`): simulate, fit (resumable: the same
command continues an interrupted run exactly), then package and evaluate into the zoo. A recipe
that fine-tunes (``Recipe.init``) starts from that entry's verified weights, found in ``--zoo``
or else in the default zoo; a published-data recipe needs ``--data`` (the data set's folder).
``real`` scores a depth entry on the C3VD phantom clip (:mod:`c3f_models.zoo.real`), stores the
numbers in its ``evaluation.json`` and renders its card and the zoo's index again. Bad input is
one ``error: ...`` line and exit status 2.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from c3f_core.cli_parser import OneLineParser, run_subcommand
from c3f_core.errors import InputError
from c3f_models.zoo.real import EVERY
from c3f_slam.models import zoo


def _parser() -> argparse.ArgumentParser:
    p = OneLineParser(prog="python -m c3f_models zoo", description="The model zoo (zoo/ in the repository).")
    p.add_argument("--zoo", type=Path, help=f"zoo folder (default: ${zoo.ENV} or the repository's zoo/)")
    sub = p.add_subparsers(dest="command", required=True)
    sub.add_parser("list", help="the entries, their kind and headline numbers")
    s = sub.add_parser("show", help="one entry's model card")
    s.add_argument("name")
    s.add_argument("--json", action="store_true", help="the card's machine-readable front matter as JSON")
    v = sub.add_parser("verify", help="check every file's SHA-256 against its card")
    v.add_argument("names", nargs="*", help="entries (default: all)")
    sub.add_parser("recipes", help="the recipes that `train` knows")
    t = sub.add_parser("train", help="run a recipe: simulate, train (resumable), evaluate, export into the zoo")
    t.add_argument("name", help="recipe name (see `recipes`)")
    t.add_argument("--data", type=Path,
                   help="the data set's folder, as published or converted (recipes of a published data set only)")
    t.add_argument("--work", type=Path, help="work folder (default: runs/zoo/NAME); rerun to resume")
    t.add_argument("--heldout", type=Path, help="folder of the held-out sequences (default: runs/zoo/heldout)")
    t.add_argument("--max-minutes", type=float, help="stop training after this long (it resumes where it stopped)")
    t.add_argument("--quick", action="store_true",
                   help="3 steps on tiny sequences: checks the recipe end to end, trains nothing useful "
                        "(entry NAME-quick)")
    t.add_argument("--jobs", type=int, default=2, help="simulator processes at a time (default 2)")
    t.add_argument("--trainer-config", type=Path,
                   help="a trainer preset composed after the recipe's config, e.g. configs/trainer/gpu.yaml "
                        "(default: the recipe's CPU settings)")
    r = sub.add_parser("real", help="a depth entry on the real frames of the C3VD phantom clip: Spearman with its "
                                    "depth render, into the entry's evaluation.json and card")
    r.add_argument("name", help="a depth entry of the zoo")
    r.add_argument("--phantom", type=Path, required=True,
                   help="the phantom clip's folder (with split.py) or its split (rgb/, depth_render/, occlusion/, "
                        "camera.json); never in the repository")
    r.add_argument("--every", type=int, default=EVERY, help=f"take every N-th frame of the clip (default {EVERY})")
    r.add_argument("--ttt-steps", type=int, default=0,
                   help="test-time training steps (batch 4) from the entry's weights on the clip before scoring "
                        "again (default 0: none; 60 take about 5 minutes on 2 CPU cores)")
    r.add_argument("--work", type=Path, help="work folder for the split clip and test-time training "
                                             "(default: runs/zoo/real)")
    return p


def _root(args: argparse.Namespace) -> Path:
    return args.zoo if args.zoo is not None else zoo.zoo_root()


def _list(args: argparse.Namespace) -> int:
    from c3f_models.zoo.card import real_summary, summary_numbers

    found = zoo.entries(_root(args))
    if not found:
        print(f"no models in {_root(args)}")
    for e in found:
        real = real_summary(e.own)
        print(f"{e.name:28s} {e.kind:12s} {e.summary}\n{'':41s}{summary_numbers(e.metrics)}"
              + (f"\n{'':41s}real frames: {real}" if real else ""))
    return 0


def _show(args: argparse.Namespace) -> int:
    e = zoo.entry(args.name, "zoo show", _root(args))
    if args.json:
        print(json.dumps(e.meta, indent=2, default=str))
    else:
        print((e.folder / zoo.CARD).read_text(encoding="utf-8"))
    return 0


def _verify(args: argparse.Namespace) -> int:
    root = _root(args)
    found = [zoo.entry(n, "zoo verify", root) for n in args.names] if args.names else zoo.entries(root)
    for e in found:
        for f in e.files.values():
            e.verify(f, "zoo verify")
            print(f"ok  {e.name}/{f.name}  {f.sha256[:16]}")
    return 0


def _recipes(args: argparse.Namespace) -> int:
    from c3f_models.zoo.recipes import RECIPES

    for r in RECIPES.values():
        print(f"{r.name:28s} {r.kind:12s} {r.steps:6d} steps  {r.summary}" + (" (--data DIR)" if r.dataset else ""))
    return 0


def _init_weights(name: str, kind: str, root: Path) -> Path:
    """The verified weights file of zoo entry ``name``: in ``root``, else in the default zoo."""
    where = root if (root / name / zoo.CARD).is_file() else zoo.zoo_root()
    return zoo.entry(name, "zoo train", where).file_for("weights", "zoo train", kind=kind)


def _data_folder(name: str, recipe, data: Path | None) -> Path | None:
    """The ``--data`` folder of a published-data recipe (InputError when missing or given to another)."""
    if recipe.dataset is None:
        if data is not None:
            raise InputError(f"--data: recipe {name} trains on simulator sequences and takes no data folder")
        return None
    if data is None:
        raise InputError(f"--data: recipe {name} needs the {recipe.dataset} folder (zoo train NAME --data DIR)")
    if not data.is_dir():
        raise InputError(f"--data: folder not found: {data}")
    return data.resolve()


def _train(args: argparse.Namespace) -> int:
    from c3f_models.zoo.package import package
    from c3f_models.zoo.recipes import HELD_OUT, QUICK_HELD_OUT, RECIPES, quick
    from c3f_models.zoo.train import REPO, RecipeRun, default_work, fit, simulate

    if args.name not in RECIPES:
        raise InputError(f"zoo train: no recipe {args.name!r} (there are: {', '.join(RECIPES)})")
    recipe = quick(RECIPES[args.name]) if args.quick else RECIPES[args.name]
    source = _data_folder(args.name, recipe, args.data)
    if args.trainer_config is not None and not args.trainer_config.is_file():
        raise InputError(f"--trainer-config: file not found: {args.trainer_config}")
    init = _init_weights(recipe.init, recipe.kind, _root(args)) if recipe.init else None
    run = RecipeRun(recipe, args.work or default_work(recipe.name), init=init, source=source)
    heldout, heldout_root = (QUICK_HELD_OUT, run.work / "heldout") if args.quick else (HELD_OUT, None)
    heldout_root = args.heldout or heldout_root or REPO / "runs" / "zoo" / "heldout"
    if source is None:
        print(f"[{recipe.name}] simulate {len(recipe.train) + len(recipe.val)} sequences into {run.data}", flush=True)
        simulate(recipe.train + recipe.val, recipe.size, run.data, args.jobs)
    print(f"[{recipe.name}] fit to {recipe.steps} steps" + (f" from zoo:{recipe.init}" if init else "")
          + f" (log: {run.log})", flush=True)
    if not fit(run, recipe.steps, args.max_minutes, args.trainer_config):
        print(f"[{recipe.name}] stopped after --max-minutes {args.max_minutes:g}; the same command continues")
        return 0
    print(f"[{recipe.name}] package: float16 weights, ONNX, held-out evaluation, model card", flush=True)
    dest = package(run, _root(args), heldout, heldout_root)
    print(f"[{recipe.name}] wrote {dest}")
    return 0


def _real(args: argparse.Namespace) -> int:
    from c3f_models.zoo.card import card_inputs, rho_text
    from c3f_models.zoo.real import measure, record
    from c3f_models.zoo.train import REPO

    e = zoo.entry(args.name, "zoo real", _root(args))
    e.file_for("depth", "zoo real")  # a descriptors entry: refused in one line
    card_inputs(e.folder)  # a card that cannot be made again: refused before anything runs
    real = measure(e, args.phantom, args.work or REPO / "runs" / "zoo" / "real", every=args.every,
                   ttt_steps=args.ttt_steps)
    card = record(e, real)
    after = f", after {args.ttt_steps} test-time training steps {rho_text(real['after']['spearman'])}" \
        if "after" in real else ""
    print(f"zoo:{e.name} on {len(real['frames'])} phantom frames: Spearman {rho_text(real['before']['spearman'])}"
          f"{after}; darker is farther {rho_text(real['darker_is_farther'])} (mean (median; pooled)) -> {card}")
    return 0


COMMANDS = {"list": _list, "show": _show, "verify": _verify, "recipes": _recipes, "train": _train, "real": _real}


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    return run_subcommand(COMMANDS, args, "; the same command resumes" if args.command == "train" else "")


__all__ = ["main"]
