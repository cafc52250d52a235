"""A zoo recipe end to end at toy size (``zoo train NAME --quick``: 3 steps on tiny sequences):
simulate, fit, float16 weights, ONNX export with float16 storage, held-out evaluation, model
card; the entry then loads by name in the runtime and as ``--model.init_weights``, its card's
numbers read back equal the evaluation's, and a rerun does not train again. The second version
fine-tunes the first one's weights on randomised looks. Fast checks of the recipes' data come first."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from c3f_models.zoo.card import headline
from c3f_models.zoo.cli import main as zoo_main
from c3f_models.zoo.recipes import HELD_OUT, RECIPES, quick
from c3f_models.zoo.train import RecipeRun, generate_command, write_fit_yaml
from c3f_slam.models import zoo
from datamodules.synthetic.randomize import sample_look, set_args

NAME = "c3f-depth-r18w32"
V2 = ("c3f-depth-r18w32-v2", "c3f-features-r18w32-v2")


def e2e(test):
    """Marks a test that runs the project's commands end to end, for minutes."""
    return pytest.mark.e2e(pytest.mark.long(test))


def test_v2_sequences_are_new_looks_apart_from_held_out_and_v1():
    held = {s.seed for s in HELD_OUT}
    v1 = {s.seed for r in (RECIPES[NAME], RECIPES["c3f-features-r18w32"]) for s in r.train + r.val}
    for name in V2:
        r = RECIPES[name]
        specs = r.train + r.val
        assert r.init == name.removesuffix("-v2") and name.removesuffix("-v2") in RECIPES
        assert len({s.name for s in specs}) == len(specs) == 16
        assert all(s.look is not None and s.name.endswith(f"_l{s.look}") for s in specs)
        assert not {s.seed for s in specs} & (held | v1) and not {s.look for s in specs} & (held | v1)
        assert {s.preset for s in r.train} == {"seq1", "seq2", "seq3", "seq4", "seq6", "seq7", "seq8"}
        assert any("fine-tuned" in d for d in r.deviations) and any("recording" in d for d in r.deviations)
        assert any(" h" in d and "estimate" in d for d in r.deviations)
    assert all(s.preset != "seq5" for r in RECIPES.values() for s in r.train + r.val)


def test_generate_command_appends_the_look(tmp_path):
    spec = RECIPES[V2[0]].train[0]
    cmd = generate_command(spec, 128, tmp_path / spec.name)
    items = sample_look(spec.look)
    assert any(i.startswith("recording.") for i in items)
    tail = cmd[cmd.index("--out") - 2 * len(items):cmd.index("--out")]
    assert tuple(tail) == set_args(items)
    plain = generate_command(RECIPES[NAME].train[0], 128, tmp_path / "x")
    assert not any(a.startswith(("appearance.", "recording.")) for a in plain)


def test_fit_yaml_starts_from_the_init_weights(tmp_path):
    r = quick(RECIPES[V2[0]])
    assert r.init == NAME and len(r.train) == 2 and all(s.look is not None for s in r.train)
    cfg = yaml.safe_load(write_fit_yaml(RecipeRun(r, tmp_path, init=tmp_path / "w.safetensors"), 3).read_text())
    assert cfg["model"]["init_args"]["init_weights"] == str(tmp_path / "w.safetensors")
    assert cfg["data"]["init_args"]["split"]["train"] == [s.name for s in r.train]
    cfg = yaml.safe_load(write_fit_yaml(RecipeRun(quick(RECIPES[NAME]), tmp_path), 3).read_text())
    assert "model" not in cfg


@pytest.fixture(scope="module")
def quick_entry(tmp_path_factory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("zoo_recipe")
    work, zoo_dir = root / "work", root / "zoo"
    assert zoo_main(["--zoo", str(zoo_dir), "train", NAME, "--quick", "--work", str(work)]) == 0
    return work, zoo_dir / f"{NAME}-quick"


@e2e
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


@e2e
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


@e2e
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


@e2e
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


@e2e
def test_rerun_skips_training(quick_entry):
    work, entry_dir = quick_entry
    chunks = len(json.loads((work / "recipe.json").read_text())["chunks"])
    assert zoo_main(["--zoo", str(entry_dir.parent), "train", NAME, "--quick", "--work", str(work)]) == 0
    assert len(json.loads((work / "recipe.json").read_text())["chunks"]) == chunks


@e2e
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


@e2e
def test_v2_fine_tunes_the_first_version(tmp_path):
    """The v2 depth recipe at toy size: sequences of randomised looks with recording effects, a fit
    that starts from the first version's zoo weights (3 steps at lr 1e-4 stay within float16 rounding
    and AdamW's steps of them; from scratch they would not), an entry that loads in the runtime."""
    from safetensors.torch import load_file

    from c3f_slam.models.nets import DepthModel

    name, zoo_dir, work = V2[0], tmp_path / "zoo", tmp_path / "work"
    assert zoo_main(["--zoo", str(zoo_dir), "train", name, "--quick", "--work", str(work)]) == 0
    spec = quick(RECIPES[name]).train[0]
    recorded = json.loads((work / "data" / spec.name / "recording.json").read_text())
    assert recorded and (work / "data" / spec.name / "covered").is_dir()
    fit = yaml.safe_load((work / "fit.yaml").read_text())
    assert Path(fit["model"]["init_args"]["init_weights"]) == zoo.zoo_root() / NAME / "weights.safetensors"
    v1 = load_file(zoo.zoo_root() / NAME / "weights.safetensors")
    v2 = load_file(zoo_dir / f"{name}-quick" / "weights.safetensors")
    key = "depth_net.encoder.conv1.weight"
    diff = (v1[key].float() - v2[key].float()).abs().max().item()
    assert 0 < diff < 5e-3
    entry = zoo.read_entry(zoo_dir / f"{name}-quick")
    assert entry.meta["c3fusion"]["training"]["init"] == f"zoo:{NAME}"
    assert "randomised looks" in (entry.folder / "README.md").read_text()
    assert DepthModel(str(entry.folder / "depthnet.onnx")).metric_scale is not None
