"""The runtime's settings tree: presets, --config files, --set overrides, --print-config,
and a run replayed from its summary.json."""

from __future__ import annotations

import json
from dataclasses import fields, is_dataclass
from pathlib import Path

import pytest
import yaml

from c3f_core.errors import InputError
from c3f_core.settings import field_docs
from c3f_slam.cli.main import main
from c3f_slam.config import PRESETS, SlamConfig, config_from_dict, preset
from c3f_slam.config.loading import config_yaml, read_config_file, resolve_config
from datamodules.synthetic.fixture import make_tiny_sequence


def _leaves(tree, prefix=""):
    for f in fields(tree):
        value = getattr(tree, f.name)
        if is_dataclass(value):
            yield from _leaves(value, f"{prefix}{f.name}.")
        else:
            yield type(tree), f.name, prefix + f.name


def test_every_setting_has_a_meaning():
    """--print-config explains every setting: each leaf field carries a ``#:`` comment."""
    missing = [path for cls, name, path in _leaves(SlamConfig()) if name not in field_docs(cls)]
    assert missing == []


@pytest.mark.parametrize("name", list(PRESETS))
def test_print_config_reads_back_as_the_same_tree(name, tmp_path):
    text = config_yaml(PRESETS[name])
    assert "# float: metres: voxel edge" in text or "voxel edge" in text
    path = tmp_path / "cfg.yaml"
    path.write_text(text)
    assert resolve_config(None, read_config_file(path)) == PRESETS[name]
    assert config_from_dict(yaml.safe_load(text)) == PRESETS[name]


def test_presets_are_complete_instances():
    colon, room = PRESETS["colon"], PRESETS["room"]
    assert colon == SlamConfig() and room.preset == "room"
    assert room.fusion.tsdf.voxel_size == 0.01 and room.match_filter.max_residual == 0.02
    assert room.posegraph.max_correspondence_distance == 0.07 and not room.coverage.enabled
    with pytest.raises(InputError, match="preset must be one of"):
        preset("galaxy")


def test_set_converts_by_field_type_and_last_wins():
    cfg = resolve_config("room", None, ["fragments.min_overlap=0.8", "frontend.ratio=none",
                                        "fusion.tsdf.voxel_size=0.02", "keyframes.reuse=false", "frames.stride=2",
                                        "frames.stride=3", "refine.voxels=0.1,0.05", "refine.iterations=[5, 5]"])
    assert cfg.preset == "room" and cfg.fragments.min_overlap == 0.8 and cfg.frontend.ratio is None
    assert cfg.fusion.tsdf.voxel_size == 0.02 and cfg.fusion.tsdf.depth_max == 4.0  # the rest stays room's
    assert cfg.keyframes.reuse is False and cfg.frames.stride == 3
    assert cfg.refine.voxels == (0.1, 0.05) and cfg.refine.iterations == (5, 5)  # checked together
    assert resolve_config(None, None, ["refine={voxels: [0.1], iterations: [3]}"]).refine.iterations == (3,)


@pytest.mark.parametrize("item, message", [
    ("fragmens.min_overlap=0.8", "unknown setting 'fragmens'"),
    ("fragments.overlap=0.8", "unknown setting 'fragments.overlap'"),
    ("fragments.max_frames=1.5", "fragments.max_frames: cannot use '1.5' (expected int)"),
    ("fragments.min_overlap=1.5", "fragments.min_overlap must be in [0, 1], got 1.5"),
    ("keyframes.reuse=maybe", "keyframes.reuse: cannot use 'maybe' (expected bool)"),
    ("fusion.tsdf.trunc=0", "fusion.tsdf.voxel_size and fusion.tsdf.trunc must be > 0"),
    ("frames.stride.x=1", "frames.stride: cannot use {'x': '1'} (expected int)"),
    ("mode=fast", "mode must be one of"),
    ("novalue", "expected part.field=VALUE"),
])
def test_bad_set_names_the_setting(item, message):
    with pytest.raises(InputError) as exc:
        resolve_config(None, None, [item])
    assert message in str(exc.value) and "\n" not in str(exc.value)


def test_config_files(tmp_path):
    part = tmp_path / "part.yaml"
    part.write_text("preset: room\nfragments:\n  min_overlap: 0.7\n")
    cfg = resolve_config(None, read_config_file(part), ["fragments.min_overlap=0.75"])
    assert cfg.preset == "room" and cfg.fragments.min_overlap == 0.75 and cfg.fusion.tsdf == PRESETS["room"].fusion.tsdf
    js = tmp_path / "cfg.json"
    js.write_text(json.dumps({"coverage": {"segment": 0.02}}))
    assert resolve_config(None, read_config_file(js)).coverage.segment == 0.02
    with pytest.raises(InputError, match="--preset colon contradicts preset: room"):
        resolve_config("colon", read_config_file(part))
    bad = tmp_path / "bad.yaml"
    bad.write_text("fragments:\n  min_overlap: [0.7\n")
    with pytest.raises(InputError, match=r"--config: .*bad.yaml is not valid YAML"):
        read_config_file(bad)
    bad.write_text("- 1\n- 2\n")
    with pytest.raises(InputError, match="must hold a mapping of settings, got list"):
        read_config_file(bad)
    bad.write_text("fusion:\n  tsdf:\n    voxels: 0.1\n")
    with pytest.raises(InputError, match=r"--config .*bad.yaml: unknown setting 'fusion.tsdf.voxels'"):
        resolve_config(None, read_config_file(bad))
    with pytest.raises(InputError, match="--config: .*nope.yaml not found"):
        read_config_file(tmp_path / "nope.yaml")


def test_print_config_command(capsys):
    assert main(["run", "--preset", "room", "--set", "fusion.tsdf.voxel_size=0.02", "--set", "fusion.enabled=false",
                 "--print-config"]) == 0
    cfg = config_from_dict(yaml.safe_load(capsys.readouterr().out))
    assert cfg.preset == "room" and cfg.fusion.tsdf.voxel_size == 0.02 and not cfg.fusion.enabled


def test_bad_config_file_is_one_line(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text("fragments: {min_overlap: 3}\n")
    out = tmp_path / "out"
    assert main(["run", str(tmp_path), "--out", str(out), "--config", str(bad), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"error: --config {bad}: fragments.min_overlap must be in [0, 1], got 3.0"]
    assert not out.exists()  # settings are read before the run folder is claimed


@pytest.fixture(scope="module")
def seq(tmp_path_factory) -> Path:
    return make_tiny_sequence(tmp_path_factory.mktemp("cfg") / "seq", frames=16, size=96, seed=3)


def test_summary_json_replays_the_run_byte_for_byte(seq, tmp_path, capsys):
    """``run SEQ --config OLD/summary.json --out NEW`` gives the same trajectory file, byte for byte,
    and the same settings, also with non-default settings and frame selection."""
    old, new = tmp_path / "old", tmp_path / "new"
    assert main(["run", str(seq), "--out", str(old), "--set", "frames.stride=1", "--set", "frames.max_frames=14",
                 "--set", "fusion.enabled=false", "--quiet",
                 "--set", "fragments.min_overlap=0.9", "--set", "frontend.max_keypoints=400",
                 "--set", "keyframes.max_loop_edges=3"]) == 0
    assert main(["run", str(seq), "--out", str(new), "--config", str(old / "summary.json"), "--quiet"]) == 0
    a, b = (json.loads((d / "summary.json").read_text()) for d in (old, new))
    assert a["config"] == b["config"] and b["config"]["frames"]["max_frames"] == 14
    assert b["config"]["fragments"]["min_overlap"] == 0.9 and a["frames"] == b["frames"] == 14
    assert (old / "trajectory.txt").read_bytes() == (new / "trajectory.txt").read_bytes()
    assert "warning" not in capsys.readouterr().err
