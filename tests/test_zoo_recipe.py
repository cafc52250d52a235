"""A zoo recipe end to end at toy size (``zoo train NAME --quick``: 3 steps on tiny sequences):
simulate, fit, float16 weights, ONNX export with float16 storage, held-out evaluation, model
card; the entry then loads by name in the runtime and as ``--model.init_weights``, its card's
numbers read back equal the evaluation's, and a rerun does not train again."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from c3f_models.zoo.card import headline
from c3f_models.zoo.cli import main as zoo_main
from c3f_models.zoo.recipes import RECIPES, quick
from c3f_slam.models import zoo

pytestmark = [pytest.mark.e2e, pytest.mark.long]  # every test here runs the project's commands end to end, for minutes

NAME = "c3f-depth-r18w32"


@pytest.fixture(scope="module")
def quick_entry(tmp_path_factory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("zoo_recipe")
    work, zoo_dir = root / "work", root / "zoo"
    assert zoo_main(["--zoo", str(zoo_dir), "train", NAME, "--quick", "--work", str(work)]) == 0
    return work, zoo_dir / f"{NAME}-quick"


def test_entry_files_and_hashes(quick_entry):
    _, entry_dir = quick_entry
    e = zoo.read_entry(entry_dir)
    assert e.kind == "depth"
    assert {f.role for f in e.files.values()} == {"depth", "weights"}
    for f in e.files.values():
        assert e.verify(f, "test") == entry_dir / f.name
    assert (entry_dir / "config.yaml").is_file() and (entry_dir / "evaluation.json").is_file()
    meta = e.meta
    assert meta["license"] == "apache-2.0" and meta["model-index"][0]["results"][0]["metrics"]


def test_card_numbers_read_back(quick_entry):
    _, entry_dir = quick_entry
    results = json.loads((entry_dir / "evaluation.json").read_text())
    want = headline(quick(RECIPES[NAME]), results)
    got = zoo.read_entry(entry_dir).metrics
    assert set(got) == {k for k, v in want.items() if not np.isnan(v)}
    for k, v in got.items():
        assert v == pytest.approx(want[k], abs=1e-5)
    card = (entry_dir / "README.md").read_text()
    assert "QUICK CHECK" in card and f"zoo train {NAME} --quick" in card
    assert "## Deviations from the paper" in card and "## Files" in card


def test_onnx_stores_float16_and_runs_by_name(quick_entry, monkeypatch):
    import onnx

    from c3f_slam.models.nets import DepthModel

    _, entry_dir = quick_entry
    graph = onnx.load(entry_dir / "depthnet.onnx").graph
    big = [i for i in graph.initializer if np.prod(i.dims) >= 16]
    assert big and all(i.data_type == onnx.TensorProto.FLOAT16 for i in big)
    monkeypatch.setenv(zoo.ENV, str(entry_dir.parent))
    model = DepthModel(f"zoo:{entry_dir.name}")
    assert model.metric_scale is not None and model.metadata.parity["max_abs_diff"] <= 1e-4


def test_weights_start_a_model_by_name(quick_entry, monkeypatch):
    import torch

    from c3f_models.depth.module import DepthNet

    _, entry_dir = quick_entry
    monkeypatch.setenv(zoo.ENV, str(entry_dir.parent))
    args = yaml.safe_load((entry_dir / "config.yaml").read_text())["model"]["init_args"]
    net = DepthNet(**{**args, "init_weights": f"zoo:{entry_dir.name}"})
    net.setup("fit")
    w = net.state_dict()["depth_net.encoder.conv1.weight"]
    assert torch.equal(w, w.half().float())  # the float16 weights, loaded into float32


def test_rerun_skips_training(quick_entry):
    work, entry_dir = quick_entry
    chunks = len(json.loads((work / "recipe.json").read_text())["chunks"])
    assert zoo_main(["--zoo", str(entry_dir.parent), "train", NAME, "--quick", "--work", str(work)]) == 0
    assert len(json.loads((work / "recipe.json").read_text())["chunks"]) == chunks


def test_descriptor_recipe_end_to_end(tmp_path, monkeypatch):
    """The ContraFeat recipe at toy size: float32 ONNX storage, float16 weights, card numbers read
    back, loadable by name in the runtime and as init_weights."""
    from c3f_models.contrafeat.module import ContraFeat
    from c3f_slam.models.nets import DescriptorModel

    name = "c3f-features-r18w32"
    zoo_dir = tmp_path / "zoo"
    assert zoo_main(["--zoo", str(zoo_dir), "train", name, "--quick", "--work", str(tmp_path / "work")]) == 0
    entry = zoo.read_entry(zoo_dir / f"{name}-quick")
    assert entry.kind == "descriptors" and {f.role for f in entry.files.values()} == {"descriptors", "weights"}
    results = json.loads((entry.folder / "evaluation.json").read_text())
    want = headline(quick(RECIPES[name]), results)
    assert entry.metrics == pytest.approx({k: v for k, v in want.items() if not np.isnan(v)}, abs=1e-5)
    assert "descriptors_float32" in results
    monkeypatch.setenv(zoo.ENV, str(zoo_dir))
    assert DescriptorModel(f"zoo:{entry.name}").metadata.descriptor_dim == 128
    args = yaml.safe_load((entry.folder / "config.yaml").read_text())["model"]["init_args"]
    ContraFeat(**{**args, "init_weights": f"zoo:{entry.name}"}).setup("fit")
    assert f"[{entry.name}]({entry.name}/README.md)" in (zoo_dir / "README.md").read_text()  # the index
