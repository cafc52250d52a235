"""The settings options every command shares (c3f_core.settings_cli): preset, file, --set, in that
order; a record's settings replayed; the YAML read back; one-line errors naming the option."""

import argparse
import json
from dataclasses import dataclass, field

import pytest

from c3f_core.cli_parser import OneLineParser
from c3f_core.errors import InputError
from c3f_core.settings_cli import SettingsSpec, add_settings_options, read_config_file


@dataclass(frozen=True)
class Part:
    """A group."""

    size: int = 3  #: pixels
    scale: float | None = None  #: metres, none: unscaled

    def __post_init__(self):
        if self.size <= 0:
            raise InputError(f"part.size must be > 0, got {self.size}")


@dataclass(frozen=True)
class Tree:
    """The root."""

    preset: str = "small"  #: the preset this tree started from
    name: str = "a"
    part: Part = field(default_factory=Part)


TOY = SettingsSpec(presets={"small": Tree, "big": lambda: Tree(preset="big", part=Part(size=9))},
                    default="small", record_key="settings", usage="python -m toy --config THIS_FILE")


def _args(argv):
    ap = OneLineParser(prog="toy")
    add_settings_options(ap, TOY, example="part.size=4", replay="an earlier run's record.json")
    return ap.parse_args(argv)


def test_order_is_preset_then_file_then_set(tmp_path):
    f = tmp_path / "c.yaml"
    f.write_text("preset: big\nname: b\npart: {scale: 0.5}\n")
    tree = TOY.from_args(_args(["--config", str(f), "--set", "part.scale=none", "--set", "name=c"]))
    assert tree == Tree(preset="big", name="c", part=Part(size=9, scale=None))


def test_yaml_reads_back_and_records_replay(tmp_path):
    tree = TOY.resolve("big", None, ["part.scale=0.25"])
    text = TOY.yaml(tree)
    assert text.startswith("# C3Fusion settings: python -m toy") and "size: 9  # int: pixels" in text
    (tmp_path / "p.yaml").write_text(text)
    assert TOY.resolve(None, read_config_file(tmp_path / "p.yaml")) == tree
    record = tmp_path / "record.json"
    record.write_text(json.dumps({"settings": {"preset": "big", "part": {"scale": 0.25}}, "result": 1}))
    replay = read_config_file(record, TOY.record_key)
    assert TOY.resolve(None, replay) == tree and replay.record["result"] == 1


@pytest.mark.parametrize("argv, words", [
    (["--set", "part.size=0"], "part.size must be > 0"),
    (["--set", "part.colour=1"], "unknown setting 'part.colour'"),
    (["--set", "part.size=x"], "part.size: cannot use 'x'"),
    (["--set", "oops"], "expected part.field=VALUE"),
    (["--config", "missing.yaml"], "--config: missing.yaml not found"),
])
def test_bad_settings_are_one_line_naming_the_setting(argv, words):
    with pytest.raises(InputError, match=words.replace("(", r"\(").replace(".", r"\.")):
        TOY.from_args(_args(argv))


def test_contradicting_and_unknown_presets(tmp_path):
    f = tmp_path / "c.yaml"
    f.write_text("preset: big\n")
    with pytest.raises(InputError, match="contradicts"):
        TOY.from_args(_args(["--preset", "small", "--config", str(f)]))
    with pytest.raises(SystemExit):
        _args(["--preset", "huge"])
    with pytest.raises(InputError, match="unknown preset 'huge'"):
        TOY.resolve(None, None, ["preset=huge"])


def test_one_preset_has_no_preset_option():
    ap = argparse.ArgumentParser()
    add_settings_options(ap, SettingsSpec(presets={"default": Part}))
    assert "--preset" not in ap.format_help() and "--print-config" in ap.format_help()
