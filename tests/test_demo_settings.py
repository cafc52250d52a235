"""The demo's settings (c3f_demo.config.DEMO_SETTINGS): presets as before, --set, --config,
--print-config, one-line errors, replay from the settings a run wrote; fixed-length tuples
(c3f_core.settings.convert_value)."""

from dataclasses import replace

import pytest
import yaml

from c3f_core.errors import InputError
from c3f_core.settings import convert_value, tree_as_mapping, tree_from_mapping, type_name
from c3f_core.settings_cli import read_config_file
from c3f_demo import config as demo_cfg
from c3f_demo import runner
from c3f_demo.cli import _parser, config_of, main
from c3f_demo.config import (
    DEMO_SETTINGS,
    PRESETS,
    DemoConfig,
    DepthTrainConfig,
    FeatureTrainConfig,
    ReportConfig,
    SimulateConfig,
    ZooModels,
    demo_config,
    video_config,
)
from c3f_demo.state import STATE_FILE, DemoState


def _before(quick: bool = False, from_scratch: bool = False) -> DemoConfig:
    """demo_config as it was before the presets (its derivation, copied)."""
    if not from_scratch:
        base = _before(quick, from_scratch=True)
        sim = replace(base.simulate, train=(), train_frames=0, size=128)
        ttt = replace(base.ttt, steps=3 if quick else 60, pose_warmup_steps=1 if quick else 30)
        return replace(base, simulate=sim, ttt=ttt, zoo=ZooModels())
    if not quick:
        return DemoConfig(depth=DepthTrainConfig(lr=5e-4))
    return DemoConfig(
        simulate=SimulateConfig(train=(("seq1", 100),), train_frames=48, test_frames=40,
                                train_coverage=0.025, test_coverage=0.02),
        depth=DepthTrainConfig(steps=12, batch_size=2),
        ttt=demo_cfg.TestTimeConfig(steps=3, batch_size=2, pose_warmup_steps=1),
        features=FeatureTrainConfig(steps=6),
        report=ReportConfig(sample_frames=3, depth_eval_stride=3, pair_frame=10, render_size=240),
        quick=True,
    )


def _printed(capsys, *argv: str) -> tuple[str, DemoConfig]:
    """``--print-config`` of ``argv``: its text and the tree it reads back as."""
    assert main([*argv, "--print-config"]) == 0
    text = capsys.readouterr().out
    return text, tree_from_mapping(PRESETS["default"], yaml.safe_load(text))


@pytest.mark.parametrize(("quick", "from_scratch", "name"), [(False, False, "default"), (True, False, "quick"),
                                                              (False, True, "from-scratch"),
                                                              (True, True, "quick-from-scratch")])
def test_presets_are_the_former_ones(quick, from_scratch, name):
    assert PRESETS[name] == _before(quick, from_scratch) == demo_config(quick, from_scratch)
    flags = ["--quick"] * quick + ["--from-scratch"] * from_scratch
    assert config_of(_parser().parse_args(flags)) == PRESETS[name]
    assert config_of(_parser().parse_args(["--preset", name])) == PRESETS[name]


def test_print_config_reads_back_for_every_preset(tmp_path, capsys):
    for name, tree in PRESETS.items():
        text, back = _printed(capsys, "--preset", name)
        assert text.startswith("# C3Fusion settings: python -m c3f_demo") and back == tree
        f = tmp_path / f"{name}.yaml"
        f.write_text(text)
        assert config_of(_parser().parse_args(["--config", str(f)])) == tree  # default preset + the file
    assert "zoo: null  # ZooModels | None" in _printed(capsys, "--preset", "from-scratch")[0]
    assert not list(tmp_path.glob("*/"))  # --print-config writes nothing (no --out needed)


def test_set_changes_one_field_and_combines_with_config(tmp_path):
    cfg = config_of(_parser().parse_args(["--quick", "--set", "ttt.steps=2", "--set", "simulate.test_frames=60"]))
    assert cfg == replace(PRESETS["quick"], ttt=replace(PRESETS["quick"].ttt, steps=2),
                          simulate=replace(PRESETS["quick"].simulate, test_frames=60))
    f = tmp_path / "part.yaml"
    f.write_text("ttt: {steps: 9, lr: 0.0002}\nsimulate: {train: [[seq2, 5]]}\n")
    cfg = config_of(_parser().parse_args(["--config", str(f), "--set", "ttt.steps=4",
                                          "--set", "simulate.test=[seq3, 7]"]))
    assert (cfg.ttt.steps, cfg.ttt.lr, cfg.simulate.train, cfg.simulate.test) == (4, 2e-4, (("seq2", 5),), ("seq3", 7))
    cfg = config_of(_parser().parse_args(["--from-scratch", "--set", "simulate.train=[[a,1],[b,2]]",
                                          "--set", "zoo.depth=mine"]))
    assert cfg.simulate.train == (("a", 1), ("b", 2)) and cfg.zoo == ZooModels(depth="mine")
    assert config_of(_parser().parse_args(["--set", "zoo=none"])).zoo is None


@pytest.mark.parametrize(("argv", "message"), [
    (["--set", "ttt.steps=many"], "error: --set: ttt.steps: cannot use 'many' (expected int)"),
    (["--set", "ttt.batch_size=0"], "error: --set: ttt.batch_size must be >= 1, got 0"),
    (["--set", "ttt.nope=1"], "error: --set: unknown setting 'ttt.nope'"),
    (["--set", "simulate.test=seq1"], "error: --set: simulate.test: cannot use 'seq1' (expected tuple[str, int])"),
    (["--set", "video.max_frames=5"], "error: --set: video.path: no video given (--video FILE)"),
    (["--quick", "--preset", "default"], "error: --preset default contradicts --quick/--from-scratch"),
])
def test_bad_setting_is_one_line_and_status_2(argv, message, capsys, tmp_path):
    assert main([*argv, "--out", str(tmp_path / "d")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(message) and err.count("\n") == 1
    assert not (tmp_path / "d").exists()


def test_bad_config_file_names_it(tmp_path, capsys):
    f = tmp_path / "c.yaml"
    f.write_text("depth: {steps: -1}\n")
    assert main(["--config", str(f), "--print-config"]) == 2
    err = capsys.readouterr().err
    assert err == f"error: --config {f}: depth.steps must be >= 0, got -1\n"


def test_video_groups_combine_with_set_and_config(tmp_path, capsys):
    video = tmp_path / "v.mp4"
    video.write_bytes(b"")
    args = ["--video", str(video), "--fov", "90", "--quick", "--set", "video.max_frames=10", "--set", "ttt.steps=0"]
    cfg = config_of(_parser().parse_args(args))
    assert cfg.simulate is None and cfg.video.path == str(video) and cfg.video.fov == 90
    assert (cfg.video.max_frames, cfg.video.max_side, cfg.ttt.steps) == (10, 128, 0)
    assert cfg == replace(video_config(str(video), fov=90.0, quick=True),
                          video=replace(cfg.video, max_frames=10), ttt=replace(cfg.ttt, steps=0))
    text, back = _printed(capsys, *args)
    assert "simulate: null  # SimulateConfig | None" in text and back == cfg
    f = tmp_path / "video.yaml"
    f.write_text(text)
    assert config_of(_parser().parse_args(["--config", str(f)])) == cfg  # replays without --video
    other = tmp_path / "w.mp4"
    cfg2 = config_of(_parser().parse_args(["--config", str(f), "--video", str(other), "--fov", "70"]))
    assert (cfg2.video.path, cfg2.video.fov, cfg2.video.max_frames) == (str(other), 70, 10)  # the command line wins
    assert main(["--video", str(video), "--preset", "from-scratch", "--fov", "90", "--print-config"]) == 2
    assert "zoo: a run on a video" in capsys.readouterr().err


def test_run_writes_settings_that_replay(tmp_path, monkeypatch, capsys):
    """run_demo writes the whole tree into DIR/demo_state.json; --config that file gives it back."""

    class Noop(runner.Stage):
        name = "noop"

        def settings(self, cfg):
            return {"lr": cfg.depth.lr}

        def run(self, ctx, done=None):
            return {}

    monkeypatch.setattr(runner, "STAGES", (Noop(),))
    cfg = config_of(_parser().parse_args(["--quick", "--set", "depth.lr=0.003", "--set", "simulate.test=seq2,9"]))
    runner.run_demo(tmp_path / "d", cfg)
    capsys.readouterr()
    state = tmp_path / "d" / STATE_FILE
    assert DemoState(tmp_path / "d").config == tree_as_mapping(cfg)
    assert read_config_file(state, DEMO_SETTINGS.record_key).settings == tree_as_mapping(cfg)
    assert config_of(_parser().parse_args(["--config", str(state)])) == cfg
    text, back = _printed(capsys, "--config", str(state))
    assert back == cfg and "test: [seq2, 9]" in text
    with pytest.raises(InputError, match=f"--config {state} replays the last run's"):  # other settings: refused
        runner.run_demo(tmp_path / "d", PRESETS["quick"])
    assert config_of(_parser().parse_args(["--config", str(state)])) == cfg  # still the settings of the last run
    runner.run_demo(tmp_path / "d", PRESETS["quick"], overwrite=True)
    assert config_of(_parser().parse_args(["--config", str(state)])) == PRESETS["quick"]


def test_fixed_length_tuples_convert_from_strings_and_lists():
    pair, pairs = tuple[str, int], tuple[tuple[str, int], ...]
    assert convert_value("seq1, 200", pair, "t") == convert_value(["seq1", 200], pair, "t") == ("seq1", 200)
    assert convert_value("[[a,1],[b, 2]]", pairs, "t") == convert_value([["a", 1], ["b", 2]], pairs, "t")
    assert convert_value("[[a,1],[b, 2]]", pairs, "t") == (("a", 1), ("b", 2))
    assert convert_value("a,1", pairs, "t") == (("a", 1),) and convert_value("[]", pairs, "t") == ()
    assert convert_value("1, 2,3", tuple[float, ...], "t") == (1.0, 2.0, 3.0)  # as before
    assert type_name(pairs) == "tuple[tuple[str, int], ...]" and type_name(pair | None) == "tuple[str, int] | None"
    for bad, tp in (("a", pair), ("a,1,2", pair), ("a,b", pair), ([1], pair), ("[[a,1],x]", pairs)):
        with pytest.raises(InputError, match=r"^t: cannot use"):
            convert_value(bad, tp, "t")


def test_training_groups_map_to_fit_config_keys(tmp_path):
    """Every field of the training groups has its place in the fit config (or picks config files)."""
    from c3f_demo.context import DemoContext
    from c3f_demo.stages import FIT_KEYS, _fit_yaml, fit_keys

    cfg = PRESETS["quick-from-scratch"]
    depth = replace(cfg.depth, lr=1e-3)
    assert set(fit_keys(depth, skip=("paper_extras",))) == {FIT_KEYS[k] for k in FIT_KEYS if k != "pose_warmup_steps"}
    assert "model.init_args.optim.lr" not in fit_keys(cfg.depth, skip=("paper_extras",))  # None: the model config's
    with pytest.raises(KeyError):
        fit_keys(depth)  # paper_extras has no place in a fit config
    written = yaml.safe_load(_fit_yaml(DemoContext(tmp_path, cfg), "depthnet_ttt", fit_keys(cfg.ttt)).read_text())
    assert (written["trainer"]["max_steps"], written["seed_everything"]) == (cfg.ttt.steps, cfg.ttt.seed)
    assert written["data"]["init_args"]["loader"] == {"num_workers": 0, "batch_size": cfg.ttt.batch_size}
    assert written["model"]["init_args"] == {"optim": {"lr": cfg.ttt.lr}, "pose_warmup_steps": 1}
    assert written["trainer"]["limit_val_batches"] == 0 and len(written["trainer"]["callbacks"]) == 2
