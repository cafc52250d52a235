"""The zoo's recipes for the published data sets (SimCol3D, C3VD): ``zoo train NAME --data DIR``
fine-tunes the zoo's depth model on the folder; without ``--data`` it refuses in one line. The
paper-size GPU variants (configs/zoo/c3f-depth-r50-*-gpu.yaml) build through the CLI. End to end
(``--quick``) on a few frames written in each data set's published layout (tests/published_data.py):
fit from the zoo weights, export, and the ONNX file runs on the data set's own frames."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from c3f_models.zoo.cli import main as zoo_main
from c3f_models.zoo.recipes import DATASETS, RECIPES, quick
from c3f_models.zoo.train import RecipeRun, write_fit_yaml
from c3f_slam.models import zoo
from tests.published_data import make_published

ROOT = Path(__file__).resolve().parents[1]
PUBLISHED = {"simcol3d": "c3f-depth-r18w32-simcol3d", "c3vd": "c3f-depth-r18w32-c3vd"}
#: network input of each recipe (width, height)
SIZES = {"simcol3d": (128, 128), "c3vd": (160, 128)}


def test_recipes_name_their_data_set_and_start_from_the_zoo():
    for dataset, name in PUBLISHED.items():
        r = RECIPES[name]
        assert r.dataset == dataset and r.init == "c3f-depth-r18w32" and not r.train and not r.val
        assert r.command.endswith(f"zoo train {name} --data DIR")
        cfg = yaml.safe_load((ROOT / r.config).read_text())
        assert cfg["data"]["class_path"] == DATASETS[dataset][0]
        assert tuple(cfg["data"]["init_args"]["frames"]["size"]) == SIZES[dataset]
        assert (ROOT / f"configs/zoo/c3f-depth-r50-{dataset}-gpu.yaml").is_file()


def test_fit_yaml_reads_the_data_folder_with_its_own_split(tmp_path):
    run = RecipeRun(quick(RECIPES[PUBLISHED["c3vd"]]), tmp_path / "work", init=tmp_path / "w.safetensors",
                    source=tmp_path / "c3vd")
    cfg = yaml.safe_load(write_fit_yaml(run, 3).read_text())
    assert cfg["data"]["init_args"] == {"data_dir": str(tmp_path / "c3vd")}
    assert cfg["model"]["init_args"]["init_weights"] == str(tmp_path / "w.safetensors")


@pytest.mark.parametrize(("args", "says"), [
    (["train", "c3f-depth-r18w32-simcol3d", "--quick"], "--data: recipe c3f-depth-r18w32-simcol3d needs"),
    (["train", "c3f-depth-r18w32-c3vd", "--data", "{tmp}/none"], "--data: folder not found"),
    (["train", "c3f-depth-r18w32", "--data", "{tmp}"], "--data: recipe c3f-depth-r18w32 trains on simulator"),
])
def test_bad_data_option_is_one_line_and_exit_2(tmp_path, capsys, args, says):
    work = tmp_path / "work"
    argv = ["--zoo", str(tmp_path / "zoo"), *(a.format(tmp=tmp_path) for a in args), "--work", str(work)]
    assert zoo_main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: {says}")
    assert not work.exists() and not (tmp_path / "zoo").exists()


@pytest.mark.parametrize("dataset", sorted(PUBLISHED))
def test_gpu_variant_config_builds(dataset):
    """The paper-size variant: ResNet50 + DCN, 224 px, on one GPU (printed, not run)."""
    path = ROOT / f"configs/zoo/c3f-depth-r50-{dataset}-gpu.yaml"
    done = subprocess.run([sys.executable, "-m", "c3f_models", "fit", "--config", str(path), "--print_config"],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    cfg = yaml.safe_load(done.stdout)
    assert cfg["trainer"]["accelerator"] == "gpu" and cfg["data"]["class_path"] == DATASETS[dataset][0]
    net = cfg["model"]["init_args"]["network"]
    assert net["encoder_layers"] == 50 and net["dcn"] is True
    assert list(cfg["data"]["init_args"]["frames"]["size"]) == [224, 224]


@pytest.mark.e2e
@pytest.mark.long
@pytest.mark.parametrize("dataset", sorted(PUBLISHED))
def test_quick_fine_tune_exports_a_model_that_runs_on_the_data(tmp_path, dataset):
    from safetensors.torch import load_file

    from c3f_slam.models.nets import DepthModel
    from datamodules.formats import find_sequences, make_format

    _, data = make_published(tmp_path / "published", dataset)
    name, zoo_dir, work = PUBLISHED[dataset], tmp_path / "zoo", tmp_path / "work"
    assert zoo_main(["--zoo", str(zoo_dir), "train", name, "--quick", "--data", str(data),
                     "--work", str(work)]) == 0
    assert not (work / "data").exists()  # nothing simulated for training
    entry = zoo.read_entry(zoo_dir / f"{name}-quick")
    assert entry.meta["c3fusion"]["training"]["init"] == "zoo:c3f-depth-r18w32" and dataset in entry.meta["datasets"]
    assert "--data DIR --quick" in (entry.folder / "README.md").read_text()
    start = load_file(zoo.zoo_root() / "c3f-depth-r18w32" / "weights.safetensors")["depth_net.encoder.conv1.weight"]
    tuned = load_file(entry.folder / "weights.safetensors")["depth_net.encoder.conv1.weight"]
    assert (start.float() - tuned.float()).abs().max().item() < 5e-3  # fine-tuned from the zoo weights
    model = DepthModel(str(entry.folder / "depthnet.onnx"))
    assert tuple(model.metadata.preprocessing.size) == SIZES[dataset]
    seq = make_format(dataset).open(next(iter(find_sequences(make_format(dataset), data).values())))
    rgb = seq.read_rgb(0)
    depth = model.predict(rgb, seq.camera)
    assert depth.shape == rgb.shape[:2] and np.isfinite(depth).all() and (depth > 0).mean() > 0.5
