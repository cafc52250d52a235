"""The published data sets' LightningDataModules, their configs, and test-time training."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
import yaml

from c3f_core.errors import InputError
from c3f_models.cli import main
from datamodules.config import FramesConfig, LoaderConfig, SplitConfig
from datamodules.pairs import ContraFeatDataModule, PairSamplingConfig
from datamodules.published import C3VDDataModule, Colon10KDataModule, SimCol3DDataModule, UTSDataModule
from tests.published_data import SEQUENCE_DIR

ROOT = Path(__file__).resolve().parents[1]
MODULES = {"uts": UTSDataModule, "simcol3d": SimCol3DDataModule, "c3vd": C3VDDataModule,
           "colon10k": Colon10KDataModule}


@pytest.mark.parametrize("layout", list(MODULES))
def test_data_module_batches_and_intrinsics(published, layout):
    _, root = published(layout)
    dm = MODULES[layout](str(root), split=SplitConfig(train=None, val_fraction=0.0, test_fraction=0.0),
                         frames=FramesConfig(crop=(40, 40), size=(32, 32)), loader=LoaderConfig(batch_size=2))
    dm.setup("fit")
    batch = next(iter(dm.train_dataloader()))
    assert batch["image"].shape == (2, 3, 3, 32, 32)
    cam = dm.datasets["train"].sequences[0].camera
    K = batch["K"][0]
    assert K[0, 0] == pytest.approx(cam.fx * 32 / 40, rel=1e-5)  # the crop keeps f, the resize scales it
    assert K[0, 2] == pytest.approx((cam.cx - (cam.width - 40) // 2 + 0.5) * 32 / 40 - 0.5, rel=1e-5)
    assert ("depth" in batch) == (layout != "colon10k") and ("pose" in batch) == (layout != "colon10k")


def test_simcol3d_uses_the_release_split_and_colon10k_the_papers(published, tmp_path):
    import shutil

    root = tmp_path / "simcol"
    shutil.copytree(published("simcol3d")[1], root)
    scene = root / "SyntheticColon_C3F"
    shutil.copytree(scene / "Frames_S1", scene / "Frames_S2")
    for stem in ("SavedPosition", "SavedRotationQuaternion"):
        shutil.copy(scene / f"{stem}_S1.txt", scene / f"{stem}_S2.txt")
    (root / "misc" / "train_file.txt").write_text("SyntheticColon_C3F/Frames_S2/\n")  # a trailing '/' as in some copies
    (root / "misc" / "test_file.txt").write_text("SyntheticColon_C3F/Frames_S1\n")
    split = SimCol3DDataModule(str(root), split=SplitConfig(val_fraction=0.0)).split()
    assert [p.name for p in split["train"]] == ["Frames_S2"] and [p.name for p in split["test"]] == ["Frames_S1"]
    by_fraction = SimCol3DDataModule(str(root), published_split=False,
                                     split=SplitConfig(val_fraction=0, test_fraction=0.5)).split()
    assert [p.name for p in by_fraction["train"]] == ["Frames_S1"]
    # Colon10K: 80/20 by sequence
    src = published("colon10k")[1]
    many = tmp_path / "c10k"
    for k in range(5):
        (many / f"seq{k:02d}").mkdir(parents=True)
        (many / f"seq{k:02d}" / "image").symlink_to(src / SEQUENCE_DIR["colon10k"] / "image")
    for calib in src.glob("calib_*.txt"):
        (many / calib.name).write_text(calib.read_text())
    split = Colon10KDataModule(str(many)).split()
    assert [len(split[k]) for k in ("train", "val", "test")] == [4, 0, 1]


def test_contrafeat_pairs_from_a_published_layout(published):
    _, root = published("simcol3d")
    dm = ContraFeatDataModule(str(root), layout="simcol3d", sampling=PairSamplingConfig(gaps=(1, 2)),
                              frames=FramesConfig(size=(32, 32)), loader=LoaderConfig(batch_size=2))
    dm.setup("fit")
    batch = next(iter(dm.train_dataloader()))
    assert batch["image"].shape == (2, 2, 3, 32, 32) and batch["depth"].shape == (2, 2, 1, 32, 32)
    with pytest.raises(InputError, match=r"data.layout_options: c3vd does not take 'fov'"):
        ContraFeatDataModule(str(root), layout="c3vd", layout_options={"fov": 90})


#: the paper's crops (docs/design.md, Pre-processing): UTS renders 512 -> 400 centre crop; Colon10K's 270x216
#: scaled as they are; C3VD (ours): square crop
PAPER_CROPS = {"uts": [400, 400], "simcol3d": None, "c3vd": [1080, 1080], "colon10k": None}


@pytest.mark.parametrize("model, data", [("depthnet/full.yaml", "depthnet/uts.yaml"),
                                         ("depthnet/full.yaml", "depthnet/simcol3d.yaml"),
                                         ("depthnet/full.yaml", "depthnet/c3vd.yaml"),
                                         ("depthnet/full.yaml", "depthnet/colon10k.yaml"),
                                         ("contrafeat/full.yaml", "contrafeat/uts.yaml"),
                                         ("contrafeat/full.yaml", "contrafeat/simcol3d.yaml"),
                                         ("contrafeat/full.yaml", "contrafeat/c3vd.yaml")])
def test_data_set_configs_compose_with_the_paper_model(published, model, data, monkeypatch):
    """Each data set's config, after the paper's model config, gives the paper's settings and a
    data module that reads the simulator's files in that layout."""
    monkeypatch.chdir(ROOT)
    layout = Path(data).stem
    cli = main(["--config", f"configs/{model}", "--config", f"configs/{data}", "--trainer.logger", "false",
                "--data.data_dir", str(published(layout)[1]), "--data.frames.crop", "null",
                "--data.frames.size", "[32, 32]", "--data.split.val_fraction", "0", "--data.split.test_fraction", "0"],
               run=False)
    cfg = yaml.safe_load((ROOT / "configs" / data).read_text())["data"]
    assert type(cli.datamodule).__name__ == cfg["class_path"].rsplit(".", 1)[1]
    frames = cfg["init_args"]["frames"]
    assert frames["size"] == [224, 224] and frames.get("crop") == PAPER_CROPS[layout]  # no crop: the default
    if model.startswith("depthnet"):
        net, optim = cli.model.network_config, cli.model.optim_config
        assert (net.encoder_layers, net.dcn, optim.lr, list(optim.milestones)) == (50, True, 1e-4, [16, 24, 32])
        assert cfg["init_args"]["loader"]["batch_size"] == 16
    assert cli.datamodule.split()["train"]


def _fit_checkpoint(data: Path, tmp_path: Path) -> Path:
    main(["fit", "--config", "configs/trainer/cpu_smoke.yaml", "--config", "configs/depthnet/small.yaml",
          "--data.data_dir", str(data), "--data.frames.size", "[32, 32]", "--data.loader.batch_size", "2",
          "--trainer.max_steps", "1", "--trainer.default_root_dir", str(tmp_path / "base"),
          "--trainer.logger.init_args.save_dir", str(tmp_path / "base"), "--trainer.enable_progress_bar", "false"])
    return tmp_path / "base" / "tb" / "version_0" / "checkpoints" / "last.ckpt"


@pytest.mark.e2e
def test_test_time_training_smoke(published, tmp_path, monkeypatch):
    """ttt.yaml fine-tunes from given weights (optimiser not resumed) on all frames of one sequence."""
    monkeypatch.chdir(ROOT)
    sim, _ = published("simcol3d")
    base = _fit_checkpoint(sim, tmp_path)
    start = torch.load(base, map_location="cpu", weights_only=True)["state_dict"]
    cli = main(["fit", "--config", "configs/depthnet/small.yaml", "--config", "configs/depthnet/ttt.yaml",
                "--model.init_weights", str(base), "--data.data_dir", str(sim), "--data.frames.size", "[32, 32]",
                "--data.loader.batch_size", "2", "--trainer.max_epochs", "1", "--trainer.accelerator", "cpu",
                "--trainer.default_root_dir", str(tmp_path / "ttt"), "--trainer.logger.init_args.save_dir",
                str(tmp_path / "ttt"), "--trainer.enable_progress_bar", "false"])
    assert [p.name for p in cli.datamodule.split()["train"]] == ["sim"]  # the whole sequence, no held-out part
    assert cli.datamodule.split()["val"] == [] and cli.datamodule.split()["test"] == []
    assert list(cli.model.optim_config.milestones) == [80, 120, 170] and cli.trainer.max_epochs == 1
    ckpt = torch.load(tmp_path / "ttt" / "tb" / "version_0" / "checkpoints" / "last.ckpt", map_location="cpu",
                      weights_only=True)
    steps = len(cli.datamodule.datasets["train"]) // 2 + len(cli.datamodule.datasets["train"]) % 2
    assert ckpt["global_step"] == steps  # counted from 0: the base run's step and optimiser are not resumed
    tuned = ckpt["state_dict"]
    args = {k: v for k, v in cli.model.hparams.items() if k != "init_weights" and not k.startswith("_")}
    fresh = type(cli.model)(**args).state_dict()

    def distance(a, b):
        keys = [k for k in a if a[k].dtype.is_floating_point and "running" not in k]
        return sum(float((a[k] - b[k]).abs().sum()) for k in keys) / sum(a[k].numel() for k in keys)

    assert 0 < distance(tuned, start) < 0.1 * distance(fresh, start)  # tuned from the given weights, not from scratch


def test_test_time_training_needs_weights(published, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(ROOT)
    sim, _ = published("simcol3d")
    with pytest.raises(SystemExit) as exit_:
        main(["fit", "--config", "configs/depthnet/small.yaml", "--config", "configs/depthnet/ttt.yaml",
              "--data.data_dir", str(sim), "--data.frames.size", "[32, 32]", "--trainer.accelerator", "cpu",
              "--trainer.default_root_dir", str(tmp_path), "--trainer.logger.init_args.save_dir", str(tmp_path)])
    assert exit_.value.code == 2
    assert "model.init_weights: file not found: <the checkpoint to tune" in capsys.readouterr().err
