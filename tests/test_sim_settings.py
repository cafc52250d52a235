"""The simulator's settings (``python -m datamodules.synthetic generate``): ``--preset``,
``--config``, ``--set``, ``--print-config`` on frozen parameter groups; the former flags are
usage errors naming their replacement; a sequence's params.json replays it."""

from __future__ import annotations

import dataclasses
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from benchmarks.common.simulate import SimSequence
from c3f_core.errors import InputError
from c3f_core.settings import set_path
from c3f_core.settings_cli import read_config_file
from datamodules.synthetic.__main__ import REMOVED, _parser, removed_message
from datamodules.synthetic.__main__ import main as cli_main
from datamodules.synthetic.params import (
    SIM_SETTINGS,
    AppearanceParams,
    CameraParams,
    ColonParams,
    NuisanceParams,
    PathParams,
    SimParams,
)

ROOT = Path(__file__).resolve().parents[1]
#: a handful of changes on a paper preset: a None, a bool, an alias (rp), a string, a nuisance
SETS = ["seed=11", "path.max_turn_rate=none", "path.loop=true", "path.kind=rp", "colon.fold_height=0.45",
        "camera.width=320", "camera.height=240", "nuisance.border=Cut-Corners", "appearance.grain=2.5"]


def _run(argv: list[str], capsys) -> tuple[int, str, str]:
    """Exit status, stdout and stderr of the simulator's CLI in this process."""
    try:
        code = cli_main(argv)
    except SystemExit as exc:  # usage errors (argparse)
        code = exc.code
    out = capsys.readouterr()
    return code, out.out, out.err


def _sets(items: list[str]) -> list[str]:
    return [arg for kv in items for arg in ("--set", kv)]


# ---------------------------------------------------------------------- --print-config and --config


def test_print_config_reads_back_as_the_same_tree(tmp_path, capsys):
    expected = SIM_SETTINGS.resolve("seq3", sets=SETS)
    assert expected != SIM_SETTINGS.tree("seq3")  # the --set items change something
    assert (expected.path.kind, expected.nuisance.border, expected.path.max_turn_rate) == ("random", "cut_corners",
                                                                                          None)
    never = tmp_path / "never"
    code, text, err = _run(["generate", "--preset", "seq3", *_sets(SETS), "--print-config", "--out", str(never)],
                           capsys)
    assert code == 0 and not err and not never.exists()  # prints, writes nothing
    assert text.startswith("# C3Fusion settings: python -m datamodules.synthetic generate")
    assert "  fold_height: 0.45  # float: fold height" in text  # the field's #: comment
    cfg = tmp_path / "sim.yaml"
    cfg.write_text(text)
    assert SIM_SETTINGS.resolve(config=read_config_file(cfg, SIM_SETTINGS.record_key)) == expected
    code, again, _ = _run(["generate", "--config", str(cfg), "--print-config"], capsys)
    assert code == 0 and again == text


def test_set_applies_after_config_and_in_order(tmp_path, capsys):
    cfg = tmp_path / "partial.yaml"
    cfg.write_text("preset: seq2\npath:\n  frames: 20\ncamera: {width: 48, height: 48}\n")
    p = SIM_SETTINGS.resolve(config=read_config_file(cfg))
    assert (p.seed, p.path.kind, p.path.frames, p.camera.width) == (2, "random", 20, 48)  # seq2 under the file
    code, text, _ = _run(["generate", "--config", str(cfg), "--set", "path.frames=30", "--set", "path.frames=40",
                          "--print-config"], capsys)
    assert code == 0 and "  frames: 40  # int" in text and "\npreset: seq2  #" in text
    # --preset contradicting the file's preset is refused
    code, _, err = _run(["generate", "--config", str(cfg), "--preset", "seq1", "--print-config"], capsys)
    assert code == 2 and "contradicts preset: seq2" in err


@pytest.mark.parametrize("argv, where", [
    (["--set", "colon.fold_height=0.9"], "colon.fold_height"),
    (["--set", "camera.height=3"], "camera.height"),
    (["--set", "path.frames=1.5"], "path.frames"),
    (["--set", "nuisance.repeat_quality=0"], "nuisance.repeat_quality"),
    (["--set", "path.min_wall_distance=0.02"], "path.min_wall_distance"),  # too close to the folds of this colon
    (["--set", "colon.radius=0.006"], "colon.radius_variation"),  # the default variation no longer fits
    (["--set", "bogus.field=1"], "bogus"),
])
def test_a_bad_value_is_one_line_naming_the_field(tmp_path, capsys, argv, where):
    out = tmp_path / "never"
    code, _, err = _run(["generate", "--out", str(out), *argv], capsys)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("error: --set: ") and where in lines[0], err
    assert not out.exists()


def test_a_bad_value_in_a_config_file_names_the_file_and_field(tmp_path, capsys):
    cfg = tmp_path / "bad.yaml"
    cfg.write_text("appearance:\n  wetness: 1.5\n")
    code, _, err = _run(["generate", "--config", str(cfg), "--out", str(tmp_path / "x")], capsys)
    assert code == 2 and err.startswith(f"error: --config {cfg}: appearance.wetness:") and err.count("\n") == 1
    assert not (tmp_path / "x").exists()


# ---------------------------------------------------------------------- removed flags


def _example_sets(message: str) -> list[str]:
    """The ``--set`` items a removed flag's message names, with example values for its placeholders."""
    values = {"colon.length": "0.5", "colon.radius": "0.02", "camera.fov": "100", "path.kind": "B"}
    items = [kv.partition("=") for kv in re.findall(r"--set (\S+)", message)]
    return [f"{key}={values.get(key, '64') if value.isupper() else value}" for key, _, value in items]


@pytest.mark.parametrize("flag", list(REMOVED))
def test_removed_flag_is_one_line_naming_its_replacement(flag, capsys):
    takes_value, _ = REMOVED[flag]
    code, _, err = _run(["generate", "--out", "o", flag, *(["5"] if takes_value else [])], capsys)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1, err
    assert lines[0].startswith(f"error: {flag} was removed: use ") and removed_message(flag) in lines[0]
    if flag == "--params":
        assert "--config FILE" in lines[0]
        return
    sets = _example_sets(lines[0])
    assert sets, lines[0]
    p = SIM_SETTINGS.resolve(sets=sets)  # the named fields exist and take such values
    assert p != SimParams()


def test_removed_flags_are_hidden_from_help(capsys):
    with pytest.raises(SystemExit) as exc:
        cli_main(["generate", "--help"])
    assert exc.value.code == 0
    text = capsys.readouterr().out
    assert "--config" in text and "--print-config" in text and "--set" in text
    for flag in REMOVED:
        assert f"{flag} " not in text and f"{flag}\n" not in text, flag


def test_removed_flag_in_a_real_process(tmp_path):
    res = subprocess.run([sys.executable, "-m", "datamodules.synthetic", "generate", "--size", "128",
                          "--out", str(tmp_path / "x")], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert res.returncode == 2 and not (tmp_path / "x").exists()
    assert res.stderr.startswith("error: --size was removed: use --set camera.width=N --set camera.height=N")
    assert len(res.stderr.strip().splitlines()) == 1


# ---------------------------------------------------------------------- frozen groups


def test_groups_are_frozen_and_check_themselves():
    p = SIM_SETTINGS.tree("seq1")
    for obj, name in ((p, "seed"), (p.colon, "length"), (p.appearance, "hue"), (p.camera, "width"),
                      (p.path, "frames"), (p.nuisance, "border")):
        with pytest.raises(dataclasses.FrozenInstanceError):
            setattr(obj, name, getattr(obj, name))
    assert p == SIM_SETTINGS.tree("seq1")
    changed = set_path(p, "path.frames", "12")
    assert changed.path.frames == 12 and p.path.frames == 4500  # a new tree; the preset is untouched
    for make, where in ((lambda: ColonParams(radius=-0.01), "colon.radius"),
                        (lambda: AppearanceParams(vignette=2.0), "appearance.vignette"),
                        (lambda: CameraParams(width=8), "camera.width"),
                        (lambda: PathParams(kind="C"), "path.kind"),
                        (lambda: NuisanceParams(border="hexagon"), "nuisance.border"),
                        (lambda: ColonParams(length=float("nan")), "colon.length"),
                        (lambda: SimParams(appearance=AppearanceParams(light_offset=0.02)), "appearance.light_offset"),
                        (lambda: SimParams(preset="seq9"), "preset")):
        with pytest.raises(InputError, match=f"^{re.escape(where)}:"):
            make()
    # conversions: aliases and number types normalised on creation (so a tree equals its replay)
    assert PathParams(kind="RP").kind == "random" and NuisanceParams(border="Cut-Corners").border == "cut_corners"
    assert isinstance(ColonParams(length=1).length, float) and CameraParams(width=64.0).width == 64
    assert dataclasses.replace(PathParams(kind="b"), frames=5).kind == "B"


# ---------------------------------------------------------------------- replay and callers


def test_generate_replays_its_params_json(tmp_path, capsys):
    """A small sequence from a paper preset (nuisances on), then ``--config OLD/params.json``:
    the same params.json and byte-identical frames."""
    old, new = tmp_path / "old", tmp_path / "new"
    sets = ["seed=9", "colon.length=0.15", "colon.ring_vertices=96", "appearance.texel=0.0004",
            "path.frames=3", "path.max_step=0.004", "camera.width=48", "camera.height=40",
            "nuisance.border=circle", "nuisance.overlay=true"]
    code, out, err = _run(["generate", "--preset", "seq5", *_sets(sets), "--out", str(old), "--no-progress"], capsys)
    assert code == 0, err
    code, out, err = _run(["generate", "--config", str(old / "params.json"), "--out", str(new), "--no-progress"],
                          capsys)
    assert code == 0, err
    recorded = json.loads((old / "params.json").read_text())
    assert recorded["preset"] == "seq5" and recorded["params"]["nuisance"]["border"] == "circle"
    assert recorded == json.loads((new / "params.json").read_text())
    names = ["poses.txt", "camera.json", "tissue_mask.png", *(f"{d}/{i:06d}.png" for d in ("rgb", "depth")
                                                              for i in range(3))]
    for name in names:
        assert (new / name).read_bytes() == (old / name).read_bytes(), name
    # a changed replay differs where it was changed
    code, text, _ = _run(["generate", "--config", str(old / "params.json"), "--set", "path.frames=2",
                          "--print-config"], capsys)
    assert code == 0 and "  frames: 2  # int" in text and "\nseed: 9  #" in text


def test_callers_commands_give_the_sequence_they_describe(tmp_path):
    """The benchmarks' and the zoo's generator command lines parse and give their settings."""
    from c3f_models.zoo.recipes import SimSpec
    from c3f_models.zoo.train import generate_command

    for cmd, (preset, seed, frames, size, coverage) in (
            (SimSequence("seq2", 7, 30, 96, ("path.coverage=0.1",)).command(tmp_path / "o"), ("seq2", 7, 30, 96, 0.1)),
            (generate_command(SimSpec("seq4", 1009, 400, 0.0988), 128, tmp_path / "o"),
             ("seq4", 1009, 400, 128, 0.0988))):
        assert cmd[1:4] == ["-m", "datamodules.synthetic", "generate"]
        args = _parser().parse_args(cmd[3:])
        p = SIM_SETTINGS.from_args(args)
        assert (p.preset, p.seed, p.path.frames, p.camera.width, p.camera.height, p.path.coverage) == (
            preset, seed, frames, size, size, coverage)
        assert args.out == str(tmp_path / "o")
