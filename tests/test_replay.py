"""Every command replays the settings its runs write: the record given back with ``--config``
gives the settings tree of the original command line (compared as ``--print-config`` YAML).

Here: ``c3f_slam run`` (summary.json ``config``), ``c3f_slam batch`` (batch.json ``config``) and
``c3f_slam view`` (view.json ``settings``). The other commands' replays are tested beside their
settings (:data:`ELSEWHERE`), not again here; that those tests exist is checked.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from c3f_slam.cli.main import main
from c3f_slam.config import config_from_dict
from datamodules.synthetic.fixture import make_tiny_sequence

ROOT = Path(__file__).resolve().parents[1]
SIZE = 64  #: frame size of the tiny sequence (pixels)
#: settings of the original run / batch command lines (not the defaults, so a lost setting shows)
SLAM_SETS = ("fusion.enabled=false", "coverage.enabled=false", "frontend.max_keypoints=300",
             "fragments.min_overlap=0.85", "frames.max_frames=6", "refine.voxels=0.01,0.005", "refine.iterations=20,10")
#: settings of the original view command line
VIEW_SETS = ("budget.surface=5000", "video.crf=30", "flythrough.frames=48", "flythrough.fov_deg=90")
#: the commands whose replay is tested elsewhere: (test file, test function)
ELSEWHERE = (
    ("tests/test_sim_settings.py", "test_generate_replays_its_params_json"),  # datamodules.synthetic generate
    ("tests/test_demo_settings.py", "test_run_writes_settings_that_replay"),  # python -m c3f_demo
    ("tests/test_protocol_settings.py", "test_a_results_json_replays_its_settings"),  # benchmark protocols
    ("tests/test_slam_config.py", "test_summary_json_replays_the_run_byte_for_byte"),  # run: same outputs
)


def _sets(items: tuple[str, ...]) -> list[str]:
    return [a for item in items for a in ("--set", item)]


def _printed(argv: list[str], capsys) -> dict:
    """The settings tree ``argv`` + ``--print-config`` prints, as parsed YAML."""
    capsys.readouterr()
    assert main([*argv, "--print-config"]) == 0
    return yaml.safe_load(capsys.readouterr().out)


@pytest.fixture(scope="module")
def seq(tmp_path_factory) -> Path:
    return make_tiny_sequence(tmp_path_factory.mktemp("replay") / "seq", frames=6, size=SIZE, seed=2)


@pytest.fixture(scope="module")
def run_folder(seq, tmp_path_factory) -> Path:
    """A run of the tiny sequence with :data:`SLAM_SETS` (RGB-D, SIFT)."""
    out = tmp_path_factory.mktemp("replay_run") / "out"
    assert main(["run", str(seq), "--out", str(out), *_sets(SLAM_SETS), "--quiet"]) == 0
    return out


def test_run_replays_its_summary_json(run_folder, capsys):
    """``run --config OUT/summary.json`` gives the original command line's tree as the run
    resolved it (the thresholds derived from the frame size and depth source filled in), and
    that tree resolves to itself, so a replayed run runs with the same settings."""
    original = _printed(["run", *_sets(SLAM_SETS)], capsys)
    replayed = _printed(["run", "--config", str(run_folder / "summary.json")], capsys)
    resolved = config_from_dict(original).for_frame_size(SIZE, SIZE).for_depth_source("files")
    assert replayed == resolved.as_dict()
    assert config_from_dict(replayed).for_frame_size(SIZE, SIZE).for_depth_source("files").as_dict() == replayed
    assert replayed["fragments"]["min_overlap"] == 0.85 and replayed["refine"]["voxels"] == [0.01, 0.005]
    assert original["fragments"]["min_correspondences"] is None  # derived by the run ...
    assert isinstance(replayed["fragments"]["min_correspondences"], int)  # ... and recorded


def test_batch_replays_its_batch_json(seq, tmp_path, capsys):
    """``batch --config OUT/batch.json`` gives the original command line's tree (batch.json
    ``config``: the tree every run of the batch started from)."""
    listing = tmp_path / "list.txt"
    listing.write_text(f"{seq}\n")
    out = tmp_path / "batch"
    argv = ["batch", str(listing), "--out", str(out), "--workers", "1", "--threads", "1", "--quiet"]
    assert main([*argv, *_sets(SLAM_SETS)]) == 0
    record = json.loads((out / "batch.json").read_text())
    assert record["runs"][0]["status"] == "ok"
    original = _printed(["batch", *_sets(SLAM_SETS)], capsys)
    replayed = _printed(["batch", "--config", str(out / "batch.json")], capsys)
    assert replayed == original == record["config"]
    assert replayed != _printed(["batch"], capsys)  # the settings changed something
    # and a run's summary.json of the batch replays as run's does
    run_cfg = _printed(["run", "--config", str(out / seq.name / "summary.json")], capsys)
    assert run_cfg == config_from_dict(original).for_frame_size(SIZE, SIZE).for_depth_source("files").as_dict()


def test_view_replays_its_view_json(run_folder, capsys):
    """``view OUT --config OUT/view.json`` gives the original command line's tree, and a view
    made that way records the same tree again."""
    assert main(["view", str(run_folder), "--no-video", "--no-open", "--quiet", *_sets(VIEW_SETS)]) == 0
    record = run_folder / "view.json"
    original = _printed(["view", *_sets(VIEW_SETS)], capsys)
    replayed = _printed(["view", str(run_folder), "--config", str(record)], capsys)
    assert replayed == original == json.loads(record.read_text())["settings"]
    assert replayed["flythrough"]["frames"] == 48 and replayed != _printed(["view"], capsys)
    assert main(["view", str(run_folder), "--no-video", "--no-open", "--quiet", "--config", str(record)]) == 0
    assert json.loads(record.read_text())["settings"] == original
    # a --set after the file changes that setting only
    changed = _printed(["view", "--config", str(record), "--set", "video.fps=12"], capsys)
    assert changed["video"] == {**original["video"], "fps": 12.0} and changed["flythrough"] == original["flythrough"]


@pytest.mark.parametrize(("path", "test"), ELSEWHERE)
def test_the_other_commands_replays_are_tested_beside_their_settings(path, test):
    """The simulator, the demo and the benchmark protocols replay their records in these tests
    (and run's outputs, byte for byte); renaming one of them must update :data:`ELSEWHERE`."""
    assert f"def {test}(" in (ROOT / path).read_text()
