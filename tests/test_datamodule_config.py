"""The data modules' settings groups: defaults, validation, and the CLI (nested YAML and ``--data.GROUP.FIELD``)."""

from __future__ import annotations

from dataclasses import fields
from pathlib import Path

import pytest
import torch
import yaml

from c3f_core.errors import InputError
from c3f_models.cli import main, nulls_as_group_values
from datamodules.config import FramesConfig, LoaderConfig, SplitConfig, TupleSamplingConfig
from datamodules.pairs import ContraFeatDataModule, PairSamplingConfig
from datamodules.published import Colon10KDataModule
from datamodules.sequence import C3FSequenceDataModule

ROOT = Path(__file__).resolve().parents[1]
BORING = "lightning.pytorch.demos.boring_classes.BoringModel"
GROUPS = {"split": SplitConfig, "frames": FramesConfig, "loader": LoaderConfig}


def _cli(*args: str):
    return main(["--model", BORING, "--trainer.logger", "false", *args], run=False)


def test_cli_takes_nested_data_options_from_yaml_and_the_command_line(plane_dataset, tmp_path):
    cfg = tmp_path / "data.yaml"
    cfg.write_text(f"""
data:
  class_path: datamodules.sequence.C3FSequenceDataModule
  init_args:
    data_dir: {plane_dataset}
    frames: {{size: [24, 24], specular: false}}
    split:
      train: [plane0, plane1]
      val: []
      test: [plane2]
    loader:
      batch_size: 3
""")
    dm = _cli("--config", str(cfg), "--data.frames.crop", "[40, 40]", "--data.sampling.stride", "2").datamodule
    # a field given on the command line joins the group's fields from the YAML
    assert dm.frames_config == FramesConfig(crop=(40, 40), size=(24, 24), specular=False)
    assert dm.sampling_config == TupleSamplingConfig(stride=2) and dm.loader_config == LoaderConfig(batch_size=3)
    assert {k: [p.name for p in v] for k, v in dm.split().items()} == {
        "train": ["plane0", "plane1"], "val": [], "test": ["plane2"]}
    dm.setup("fit")
    batch = next(iter(dm.train_dataloader()))
    assert batch["image"].shape == (3, 3, 3, 24, 24) and dm.datasets["train"][0]["frame_index"].tolist() == [0, 2, 4]
    assert dm.hparams["frames"]["size"] == [24, 24]  # the resolved config, plain values


def test_cli_null_for_a_group_field(plane_dataset):
    args = ["--config", str(ROOT / "configs/contrafeat/small.yaml"), "--data.data_dir", str(plane_dataset),
            "--data.frames.crop", "[40, 40]", "--data.sampling.eval_gaps", "[1, 3]"]
    dm = _cli(*args, "--data.frames.crop", "null", "--data.sampling.eval_gaps=null").datamodule
    assert dm.frames_config == FramesConfig(crop=None, size=(128, 128))  # the YAML's size is kept
    assert dm.pairs_config == PairSamplingConfig(gaps=(1, 2, 4, 8), eval_gaps=None, eval_stride=2)
    assert nulls_as_group_values(["--data.frames.crop", "~", "--data.init_args.fov", "null", "--data.frames.size",
                                  "[8, 8]"]) == ["--data.frames", '{"crop": null}', "--data.init_args.fov", "null",
                                                 "--data.frames.size", "[8, 8]"]


@pytest.mark.parametrize("args, message", [
    (["--data.sampling.stride", "0"], "error: data.sampling.stride must be >= 1, got 0"),
    (["--data.sampling.frame_offsets", "[1, 2]"],
     "error: data.sampling.frame_offsets must contain 0 (the centre frame), got [1, 2]"),
    (["--data.frames.no_such", "1"], "no_such"),
    (["--data.size", "[32, 32]"], "size"),  # the former flat option is gone
    (["--data.loader.batch_size", "0"], "error: data.loader.batch_size must be >= 1, got 0"),  # was a traceback
    (["--data.split.val_fraction", "1.5"], "error: data.split.val_fraction must be in [0, 1], got 1.5"),
])
def test_cli_bad_data_option_is_one_line(plane_dataset, capsys, args, message):
    with pytest.raises(SystemExit) as exc:
        _cli("--data", "datamodules.sequence.C3FSequenceDataModule", "--data.data_dir", str(plane_dataset), *args)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and message in err[0]


def test_groups_validate_themselves():
    with pytest.raises(InputError, match=r"data.sampling.gaps must be a non-empty list of integers >= 1, got \[\]"):
        PairSamplingConfig(gaps=())
    with pytest.raises(InputError, match=r"data.sampling.eval_gaps must be integers >= 1, got \[0\]"):
        PairSamplingConfig(eval_gaps=(0,))
    with pytest.raises(InputError, match="data.sampling.eval_stride must be >= 1, got 0"):
        PairSamplingConfig(eval_stride=0)
    with pytest.raises(InputError, match="data.sampling.stride must be >= 1, got 0"):
        TupleSamplingConfig(stride=0)
    assert PairSamplingConfig(gaps=(1, 2), eval_gaps=()).gaps_for(train=False) == (1, 2)  # empty = the training gaps
    assert TupleSamplingConfig((-1, 0, 2), stride=3).offsets() == [-3, 0, 6]


def test_a_group_given_as_a_dict_keeps_the_modules_defaults(plane_dataset, published):
    """As the CLI fills a partly given group: ContraFeat's loader stays at batch 8, Colon10K's
    split at the paper's 80/20; an unknown field names the group."""
    dm = ContraFeatDataModule(str(plane_dataset), loader={"num_workers": 0}, frames={"size": [32, 32]})
    assert dm.loader_config == LoaderConfig(batch_size=8) and dm.frames_config == FramesConfig(size=(32, 32))
    c10k = Colon10KDataModule(str(published("colon10k")[1]), split={"test_fraction": 0.5})
    assert c10k.split_config == SplitConfig(val_fraction=0.0, test_fraction=0.5)
    with pytest.raises(InputError, match="data.frames: .*unexpected keyword argument 'batch_size'"):
        C3FSequenceDataModule(str(plane_dataset), frames={"batch_size": 2})


def test_hyper_parameters_are_plain_values(plane_dataset, tmp_path):
    """Groups are saved as dicts (a checkpoint holds no pickled class) and rebuild the same module."""
    dm = C3FSequenceDataModule(str(plane_dataset), frames=FramesConfig(size=(16, 16)), split={"val_fraction": 0.0})
    assert dm.hparams["frames"] == {"crop": None, "size": (16, 16), "specular": True}
    torch.save({"datamodule_hyper_parameters": dict(dm.hparams)}, tmp_path / "hp.pt")
    saved = torch.load(tmp_path / "hp.pt", weights_only=True)["datamodule_hyper_parameters"]
    again = C3FSequenceDataModule(**saved)
    assert (again.frames_config, again.split_config) == (dm.frames_config, dm.split_config)


@pytest.mark.parametrize("path", sorted((ROOT / "configs").glob("*/*.yaml")), ids=lambda p: f"{p.parent.name}/{p.name}")
def test_config_data_sections_use_the_groups(path):
    data = (yaml.safe_load(path.read_text()) or {}).get("data")
    if data is None:
        return
    args = data["init_args"]
    top = {"data_dir", "layout", "layout_options", "min_frames", "load_depth", "load_poses", "fov", "calibration",
           "pinhole_focal", "published_split", "split", "sampling", "frames", "loader"}
    assert set(args) <= top, set(args) - top
    pairs = data.get("class_path", "").endswith("ContraFeatDataModule")
    sampling = PairSamplingConfig if pairs else TupleSamplingConfig
    for group, cls in {**GROUPS, "sampling": sampling}.items():
        assert set(args.get(group, {})) <= {f.name for f in fields(cls)}, group
