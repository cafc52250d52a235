"""Every benchmark protocol reads its settings as every command does (benchmarks/common/protocol_cli.py):
``--print-config`` writes YAML that ``--config`` reads back to the same tree, a bad ``--set`` is one
line and exit status 2, and a results JSON (as Report.publish writes it) replays its settings.
In-process: each protocol's ``main(argv)`` stops at ``--print-config`` before any work."""

from __future__ import annotations

import importlib
import json
from pathlib import Path

import pytest
import yaml

from benchmarks.common.protocol_cli import ProtocolCli
from benchmarks.common.report import Report
from c3f_core.settings import tree_as_mapping

ROOT = Path(__file__).resolve().parents[1]
PROTOCOLS = sorted(p.stem for p in (ROOT / "benchmarks" / "protocols").glob("*.py") if p.stem != "__init__")
REQUIRED = {"trajectory_identity": ["--before", "."]}  #: the plain options a protocol requires


def _module(name: str):
    return importlib.import_module(f"benchmarks.protocols.{name}")


def _print_config(name: str, argv: list[str], capsys) -> str:
    """The YAML ``--print-config`` writes for ``argv``; it exits 0."""
    capsys.readouterr()
    with pytest.raises(SystemExit) as exit_:
        _module(name).main([*REQUIRED.get(name, []), *argv, "--print-config"])
    assert exit_.value.code in (0, None)
    return capsys.readouterr().out


def test_every_protocol_has_one_settings_class():
    assert len(PROTOCOLS) >= 17
    for name in PROTOCOLS:
        cli = _module(name).CLI
        assert isinstance(cli, ProtocolCli) and cli.name == name and cli.settings is _module(name).Settings


@pytest.mark.parametrize("name", PROTOCOLS)
def test_print_config_reads_back_to_the_same_tree(name, tmp_path, capsys):
    """The defaults as commented YAML; read back with --config (and with a changed copy) the same tree."""
    module = _module(name)
    text = _print_config(name, [], capsys)
    assert text.startswith(f"# C3Fusion settings: python -m benchmarks.protocols.{name} --config")
    default = tree_as_mapping(module.Settings())
    assert yaml.safe_load(text) == default
    cfg = tmp_path / "settings.yaml"
    cfg.write_text(text)
    assert yaml.safe_load(_print_config(name, ["--config", str(cfg)], capsys)) == default
    # a changed integer setting survives the round trip (the first int field that is not a bool)
    field = next((k for k, v in default.items() if type(v) is int), None)
    if field is not None:
        changed = yaml.safe_load(_print_config(name, ["--set", f"{field}={default[field] + 1}"], capsys))
        assert changed == {**default, field: default[field] + 1}
        cfg.write_text(yaml.safe_dump(changed))
        assert yaml.safe_load(_print_config(name, ["--config", str(cfg)], capsys)) == changed


@pytest.mark.parametrize(("name", "item", "names"), [
    ("slam_unseen", "frames=many", "frames"),
    ("slam_unseen", "nonsense=1", "nonsense"),
    ("coverage_accuracy", "cases=insertion,nowhere", "cases"),
    ("slam_ate", "methods=c3fusion", "depth_model"),
    ("zoo", "only=", "only"),
])
def test_a_bad_set_is_one_line_and_status_2(name, item, names, capsys):
    with pytest.raises(SystemExit) as exit_:
        _module(name).main([*REQUIRED.get(name, []), "--set", item, "--print-config"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2
    assert err.count("\n") == 1 and err.startswith("error: --set") and names in err, err


def test_a_results_json_replays_its_settings(tmp_path, capsys):
    """Report.publish records the whole tree under ``settings`` (the plain options apart); --config
    on that JSON gives the same tree, and --set still changes it afterwards."""
    from benchmarks.protocols import slam_tracking

    settings = slam_tracking.Settings(frames=600, sizes=(128, 256), events=("bounded", "unbounded"))
    report = Report(str(ROOT / "benchmarks" / "protocols" / "slam_tracking.py"), "Tracking", ["--set", "frames=600"])
    md = tmp_path / "slam_tracking.md"
    report.publish(md, ["| a | b |", "|---|---|", "| 1 | 2 |"], settings, options={"work": tmp_path / "w"})
    record = json.loads(md.with_suffix(".json").read_text())
    assert record["settings"] == tree_as_mapping(settings) and record["options"] == {"work": str(tmp_path / "w")}
    assert record["tables"][0]["rows"] == [[1, 2]]
    replayed = yaml.safe_load(_print_config("slam_tracking", ["--config", str(md.with_suffix(".json"))], capsys))
    assert replayed == tree_as_mapping(settings)
    changed = yaml.safe_load(_print_config("slam_tracking", ["--config", str(md.with_suffix(".json")),
                                                             "--set", "frames=300"], capsys))
    assert changed == {**tree_as_mapping(settings), "frames": 300}


def test_a_field_named_preset_is_an_ordinary_setting(capsys):
    """A simulator preset field is set like any other (not taken as the name of a settings preset)."""
    out = yaml.safe_load(_print_config("coverage_accuracy", ["--set", "preset=seq3"], capsys))
    assert out["preset"] == "seq3" and out["seed"] == 7


def test_parse_drops_the_settings_options_from_the_plain_ones(tmp_path):
    from benchmarks.protocols import slam_ate

    args, settings = slam_ate.parse_args(["--out", str(tmp_path), "--set", "presets=seq2", "--set", "mesh=true"])
    assert settings == slam_ate.Settings(presets=("seq2",), mesh=True)
    assert vars(args) == {"work": tmp_path, "report": slam_ate.RESULTS / "slam_ate.md"}
