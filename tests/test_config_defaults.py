"""Every YAML under ``configs/`` builds through the CLI's own parser, and says only what it changes.

A config file is used in the compositions of :data:`USES` (``--config`` files in order, as README,
docs/ and the files' own headers give them). One of its values is redundant when every composition
it is used in resolves to the same config without it: for a file that comes first, a value equal
to the code's default; for an override composed after others, one those already set, or the
default where none of them changes it. An override composed after any run's saved config
(:data:`AFTER_ANY_RUN`) may reset any option, so there only a value inside a list item (a
callback's arguments: a list replaces the earlier one whole) can be redundant.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from functools import cache
from pathlib import Path
from typing import Any

import lightning as L
import pytest
import torch
import yaml
from jsonargparse import Namespace
from lightning.pytorch.cli import LightningArgumentParser

from c3f_models import lightning_cli
from c3f_models.trainer import C3FTrainer

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = sorted(p.relative_to(ROOT).as_posix() for p in (ROOT / "configs").rglob("*.yaml"))

T, D, C = "configs/trainer/", "configs/depthnet/", "configs/contrafeat/"
DEPTH_DATA = ("uts", "simcol3d", "c3vd", "colon10k")
FEATURE_DATA = ("uts", "simcol3d", "c3vd")
ZOO_DEPTH, ZOO_FEATURES = "configs/zoo/c3f-depth-r18w32.yaml", "configs/zoo/c3f-features-r18w32.yaml"

#: each documented composition, ``--config`` files in order (CPU-sized ones first: a file is built
#: in the first composition it is in)
USES: tuple[tuple[str, ...], ...] = (
    (T + "cpu_smoke.yaml", D + "small.yaml"),
    (T + "cpu_smoke.yaml", D + "small.yaml", D + "monodepth2.yaml"),
    (T + "cpu_smoke.yaml", C + "small.yaml"),
    (T + "cpu_smoke.yaml", D + "small.yaml", D + "mobilenet.yaml"),
    (T + "cpu_smoke.yaml", C + "small.yaml", C + "mobilenet.yaml"),
    (D + "small.yaml", D + "ttt.yaml"),
    (T + "cpu_smoke.yaml", D + "small.yaml", D + "ttt.yaml"),
    ("zoo/c3f-depth-r18w32/config.yaml", D + "ttt.yaml", D + "paper_objective.yaml"),
    *((D + "small.yaml", f"{D}{data}.yaml") for data in DEPTH_DATA),
    *((C + "small.yaml", f"{C}{data}.yaml") for data in FEATURE_DATA),
    (ZOO_DEPTH,), (ZOO_FEATURES,), (ZOO_DEPTH, T + "gpu.yaml"), (ZOO_FEATURES, T + "gpu.yaml"),
    *((f"configs/zoo/{n}.yaml",) for n in ("c3f-depth-r18w32-v2", "c3f-features-r18w32-v2", "c3f-depth-r18w32-simcol3d",
                                            "c3f-depth-r18w32-c3vd", "c3f-depth-r50-simcol3d-gpu",
                                            "c3f-depth-r50-c3vd-gpu")),
    (T + "gpu.yaml", D + "full.yaml"),
    (T + "gpu.yaml", D + "full.yaml", D + "monodepth2.yaml"),
    (T + "gpu.yaml", C + "full.yaml"),
    (T + "ddp.yaml", D + "small.yaml"),
    (T + "ddp.yaml", D + "full.yaml"),
    *((T + "gpu.yaml", D + "full.yaml", f"{D}{data}.yaml") for data in DEPTH_DATA),
    *((T + "gpu.yaml", C + "full.yaml", f"{C}{data}.yaml") for data in FEATURE_DATA),
    (T + "gpu.yaml", D + "full.yaml", D + "c3vd.yaml", D + "ttt.yaml"),
)

#: overrides composed after the config a run saved (``zoo/NAME/config.yaml``, ``runs/.../config.yaml``)
AFTER_ANY_RUN = frozenset({D + "ttt.yaml", D + "paper_objective.yaml"})

#: what every reference keeps: class paths choose the classes; ``data_dir`` and a logger's
#: ``save_dir`` have no default
KEPT_KEYS = frozenset({"class_path", "data_dir", "save_dir"})

Key = tuple[str | int, ...]


class ParserOnly(lightning_cli.C3FCLI):
    """The CLI as :func:`c3f_models.lightning_cli.run_cli` makes it, stopped after parsing."""

    def instantiate_classes(self) -> None:
        """Nothing: the tests build each composition themselves."""


@cache
def load(path: str) -> dict:
    """The YAML of ``path`` (relative to the checkout)."""
    return yaml.safe_load((ROOT / path).read_text()) or {}


def skeleton(node: Any) -> Any:
    """``node`` with only its :data:`KEPT_KEYS` and what holds them (a list only if of classes)."""
    if isinstance(node, list):
        classes = bool(node) and all(isinstance(i, dict) and "class_path" in i for i in node)
        return [skeleton(item) for item in node] if classes else None
    if not isinstance(node, dict):
        return None
    out = {k: v for k, v in node.items() if k in KEPT_KEYS}
    for key, value in node.items():
        if key not in KEPT_KEYS and (kept := skeleton(value)):
            out[key] = kept
    return out


def leaves(node: Any, resolved: Any, key: Key = ()) -> Iterator[tuple[Key, Any]]:
    """(key, value) of each option a YAML mapping sets, split as far as the resolved config
    nests (groups, a class's arguments, lists of classes); :data:`KEPT_KEYS` left out."""
    if isinstance(node, dict) and isinstance(resolved, Namespace):
        for name, value in node.items():
            if name not in KEPT_KEYS:
                yield from leaves(value, resolved.get(name), (*key, name))
    elif isinstance(node, list) and isinstance(resolved, list) and len(node) == len(resolved) and \
            all(isinstance(r, Namespace) for r in resolved):
        for i, (item, value) in enumerate(zip(node, resolved)):
            yield from leaves(item, value, (*key, i))
    else:
        yield key, node


def at(resolved: Any, key: Key) -> Any:
    """The value at ``key`` of a resolved config (None where absent)."""
    for part in key:
        if resolved is None:
            return None
        if isinstance(part, int):
            resolved = resolved[part] if part < len(resolved) else None
        else:
            resolved = resolved.get(part)
    return resolved


def is_reset(name: str, key: Key) -> bool:
    """Whether ``name``'s value at ``key`` resets an option a run's saved config before it may change."""
    return name in AFTER_ANY_RUN and not any(isinstance(part, int) for part in key)


class Compositions:
    """The CLI's parser over the config files, each composition resolved once."""

    def __init__(self, parser: LightningArgumentParser) -> None:
        self.parser = parser
        self._resolved: dict[tuple[str, ...], Namespace] = {}

    def parse(self, texts: list[dict]) -> Namespace:
        """The resolved config of mappings given in order as ``--config`` files."""
        return self.parser.parse_args([a for t in texts for a in ("--config", yaml.safe_dump(t))])

    def resolved(self, use: tuple[str, ...]) -> Namespace:
        """The resolved config of the files of ``use`` (cached)."""
        if use not in self._resolved:
            self._resolved[use] = self.parse([load(p) for p in use])
        return self._resolved[use]

    def unchanged_without(self, use: tuple[str, ...], name: str, keys: set[Key]) -> set[Key]:
        """Those of ``keys`` (values of ``name``) that ``use`` resolves to the same without them."""
        texts, k = [load(p) for p in use], use.index(name)
        full = self.resolved(use)
        ref = self.parse([*texts[:k], skeleton(texts[k]), *texts[k + 1:]])
        return {key for key in keys if at(ref, key) == at(full, key)}

    def default(self, use: tuple[str, ...]) -> Namespace:
        """The code's defaults for the classes ``use`` chooses."""
        return self.parse([skeleton(load(p)) or {} for p in use])

    def redundant(self, name: str) -> list[str]:
        """``FILE: key = value (why)`` for each value of ``name`` that none of its compositions needs
        (the values as the first composition it is in splits them)."""
        uses = [u for u in USES if name in u]
        first = self.resolved(uses[0])
        values = dict(leaves(load(name), first))
        unneeded = set(values)
        for use in uses:
            if unneeded:
                unneeded = self.unchanged_without(use, name, unneeded)
        found = [key for key in values if key in unneeded and not is_reset(name, key)]
        default = self.default(uses[0]) if found else None
        return [f"{name}: {'.'.join(map(str, key))} = {values[key]!r} "
                f"({'the default' if at(first, key) == at(default, key) else 'set before it'})"
                for key in found]

    def build(self, use: tuple[str, ...], groups: set[str]) -> dict[str, Any]:
        """The objects of ``groups`` (model, data, trainer) that ``use`` describes, the others left
        unbuilt. A Trainer is built where its accelerator is here (a GPU preset on a machine without
        one builds its callbacks, logger and strategy only)."""
        config = self.resolved(use).clone()
        for group in {"model", "data"} - groups:
            config[group] = None
        init = self.parser.instantiate(config)
        built = {group: init[group] for group in {"model", "data"} & groups}
        trainer = init.trainer.as_dict()
        if "trainer" in groups and (trainer.get("accelerator") not in ("gpu", "cuda") or torch.cuda.is_available()):
            built["trainer"] = C3FTrainer(**trainer)
        return built


@pytest.fixture(scope="module")
def compositions() -> Compositions:
    """The CLI's parser (``run=False``: no subcommand), made once."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(lightning_cli, "C3FCLI", ParserOnly)
        mp.setattr(sys, "argv", ["c3f_models"])
        mp.chdir(ROOT)
        cli = lightning_cli.run_cli([a for p in USES[0] for a in ("--config", str(ROOT / p))], run=False)
    return Compositions(cli.parser)


def test_every_config_is_in_a_documented_composition():
    used = {p for use in USES for p in use}
    assert [p for p in CONFIGS if p not in used] == []
    assert [p for p in used if not (ROOT / p).is_file()] == []


@pytest.mark.parametrize("name", CONFIGS)
def test_config_builds(compositions, name, monkeypatch):
    """What the file configures (model, data module, trainer) builds in the first composition it is in."""
    monkeypatch.chdir(ROOT)
    groups = set(load(name)) & {"model", "data", "trainer"}
    built = compositions.build(next(u for u in USES if name in u), groups)
    kinds = {"model": L.LightningModule, "data": L.LightningDataModule, "trainer": L.Trainer}
    assert groups and groups & {"model", "data"} <= set(built)
    assert all(isinstance(obj, kinds[group]) for group, obj in built.items())


@pytest.mark.parametrize("name", CONFIGS)
def test_config_holds_only_its_changes(compositions, name):
    """No value of the file is what every composition it is in gives without it."""
    found = compositions.redundant(name)
    assert not found, "values that restate what they would be anyway:\n" + "\n".join(found)
