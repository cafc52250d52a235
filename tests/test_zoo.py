"""The model zoo: cards read back, loading by name in the runtime and the training CLI, hash
mismatch and wrong kind refused (one line, exit 2), float16 weights and ONNX storage."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import onnx
import pytest
import yaml
from onnx import TensorProto, helper, numpy_helper

from c3f_core.errors import InputError
from c3f_slam.cli.main import main as slam_main
from c3f_slam.models import zoo
from c3f_slam.models.nets import DepthModel
from c3f_slam.models.session import OnnxModel
from datamodules.synthetic.fixture import make_tiny_sequence
from tests import onnx_fixtures as fx


def _card(folder: Path, kind: str, files: dict[str, str], metrics: dict | None = None) -> None:
    """A minimal card for the files in ``folder`` (name -> role) with their true hashes."""
    listed = {n: {"role": r, "sha256": zoo.sha256_of(folder / n), "bytes": (folder / n).stat().st_size}
              for n, r in files.items()}
    meta = {"license": "apache-2.0", "library_name": "c3fusion",
            "c3fusion": {"kind": kind, "summary": f"a {kind} test entry", "files": listed,
                         "metrics": metrics or {}}}
    (folder / "README.md").write_text("---\n" + yaml.safe_dump(meta) + "---\n# test entry\n")


def _weights(path: Path, module) -> Path:
    from safetensors.torch import save_file

    from c3f_models.zoo.package import half_state

    save_file(half_state(module.state_dict()), str(path))
    return path


@pytest.fixture
def fake_zoo(tmp_path, monkeypatch) -> Path:
    """A zoo with a depth entry (closed-form ONNX depth, DepthNet weights of width 8) and a
    descriptors entry (closed-form ONNX descriptors, no weights file needed for the runtime)."""
    from c3f_models.depth.module import DepthNet

    root = tmp_path / "zoo"
    depth = root / "tiny-depth"
    depth.mkdir(parents=True)
    fx.depth_model(depth / "depthnet.onnx", size=(32, 32), dynamic=True)
    net = DepthNet(network={"encoder_width": 8, "pose_encoder_width": 8, "num_scales": 1})
    _weights(depth / "weights.safetensors", net)
    _card(depth, "depth", {"depthnet.onnx": "depth", "weights.safetensors": "weights"}, {"abs_rel": 0.08})
    desc = root / "tiny-features"
    desc.mkdir()
    fx.write(desc / "contrafeat.onnx", fx.descriptor_graph(dim=8, dynamic=True),
             fx.metadata("descriptors", dim=8, dynamic=True))
    _card(desc, "descriptors", {"contrafeat.onnx": "descriptors"})
    monkeypatch.setenv(zoo.ENV, str(root))
    return root


def test_entries_and_card_numbers(fake_zoo):
    names = [e.name for e in zoo.entries()]
    assert names == ["tiny-depth", "tiny-features"]
    e = zoo.entry("zoo:tiny-depth")
    assert e.kind == "depth" and e.metrics == {"abs_rel": 0.08}
    assert e.file_for("depth", "--depth-model") == fake_zoo / "tiny-depth" / "depthnet.onnx"


def test_unknown_name_lists_the_entries(fake_zoo):
    with pytest.raises(InputError, match=r"--depth-model: zoo:nope: no such zoo model .*tiny-depth, tiny-features"):
        zoo.resolve("zoo:nope", "depth", "--depth-model")
    with pytest.raises(InputError, match="no such zoo model"):
        zoo.entry("zoo:../tiny-depth")


def test_hash_mismatch_and_wrong_kind_refused(fake_zoo):
    with pytest.raises(InputError, match=r"--feature-model: zoo:tiny-depth is a depth model, expected a descriptors"):
        zoo.resolve("zoo:tiny-depth", "descriptors", "--feature-model")
    onnx_file = fake_zoo / "tiny-depth" / "depthnet.onnx"
    onnx_file.write_bytes(onnx_file.read_bytes() + b"\0")
    with pytest.raises(InputError, match=r"depthnet.onnx does not match its card \(SHA-256"):
        OnnxModel("zoo:tiny-depth", "depth", option="--depth-model")


def test_card_without_front_matter_refused(fake_zoo):
    (fake_zoo / "tiny-features" / "README.md").write_text("# no front matter\n")
    with pytest.raises(InputError, match="no YAML front matter"):
        zoo.entry("tiny-features")


def test_runtime_loads_by_name(fake_zoo, tmp_path, capsys):
    model = DepthModel("zoo:tiny-depth")
    assert model.onnx.path == fake_zoo / "tiny-depth" / "depthnet.onnx"
    seq = make_tiny_sequence(tmp_path / "seq", frames=6, size=64, seed=3)
    out = tmp_path / "run"
    rc = slam_main(["run", str(seq), "--depth-model", "zoo:tiny-depth", "--set", "fusion.enabled=false", "--quiet",
                    "--out", str(out)])
    assert rc in (0, 2)  # the closed-form depth need not register; the model must load
    summary = json.loads((out / "summary.json").read_text())
    assert summary["frames"] == 6
    rc = slam_main(["run", str(seq), "--depth-model", "zoo:tiny-features", "--out", str(tmp_path / "bad")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and err[-1] == ("error: --depth-model: zoo:tiny-features is a descriptors model, "
                                   "expected a depth model")
    assert not (tmp_path / "bad" / "trajectory.txt").exists()


def test_zoo_cli_list_show_verify(fake_zoo, capsys):
    from c3f_models.zoo.cli import main

    assert main(["list"]) == 0
    out = capsys.readouterr().out
    assert "tiny-depth" in out and "Abs Rel 0.080" in out
    assert main(["show", "tiny-depth", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["c3fusion"]["kind"] == "depth"
    assert main(["verify"]) == 0
    (fake_zoo / "tiny-features" / "contrafeat.onnx").write_bytes(b"tampered")
    assert main(["verify"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "does not match its card" in err[0]
    assert main(["show", "nope"]) == 2


def test_init_weights_by_name(fake_zoo):
    import torch

    from c3f_models.contrafeat.module import ContraFeat
    from c3f_models.depth.module import DepthNet

    net = DepthNet(network={"encoder_width": 8, "pose_encoder_width": 8, "num_scales": 1},
                   init_weights="zoo:tiny-depth")
    net.setup("fit")
    from c3f_models.checkpoints import read_checkpoint_weights

    stored = read_checkpoint_weights(fake_zoo / "tiny-depth" / "weights.safetensors")
    key = "depth_net.encoder.conv1.weight"
    assert stored[key].dtype == torch.float16
    assert torch.equal(net.state_dict()[key], stored[key].float())
    with pytest.raises(InputError, match="zoo:tiny-depth is a depth model, expected a descriptors model"):
        ContraFeat(init_weights="zoo:tiny-depth").setup("fit")
    wrong = DepthNet(network={"num_scales": 1}, init_weights="zoo:tiny-depth")  # full width: does not fit
    with pytest.raises(InputError, match=r"does not fit this DepthNet .*config.yaml"):
        wrong.setup("fit")


def test_fit_cli_refuses_wrong_kind_in_one_line(fake_zoo, tiny_sequence, tmp_path, capsys):
    from c3f_models.cli import main

    with pytest.raises(SystemExit) as exc:
        main(["fit", "--config", "configs/trainer/cpu_smoke.yaml", "--config", "configs/contrafeat/small.yaml",
              "--data.data_dir", str(tiny_sequence.parent), "--model.init_weights", "zoo:tiny-depth",
              "--trainer.default_root_dir", str(tmp_path / "r"),
              "--trainer.logger.init_args.save_dir", str(tmp_path / "r")])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == ("error: model.init_weights: zoo:tiny-depth is a depth model, expected a descriptors model")


def test_corrupt_safetensors_refused(tmp_path):
    from c3f_models.checkpoints import read_checkpoint_weights

    bad = tmp_path / "w.safetensors"
    bad.write_bytes(b"\x10\x00\x00\x00\x00\x00\x00\x00{not json}")
    with pytest.raises(InputError, match=r"w.safetensors is not a readable safetensors file"):
        read_checkpoint_weights(bad, "model.init_weights")


def test_half_state_refuses_values_beyond_float16():
    import torch

    from c3f_models.zoo.package import half_state

    out = half_state({"a": torch.tensor([1.0, 2.5]), "n": torch.tensor(3)})
    assert out["a"].dtype == torch.float16 and out["n"].dtype == torch.int64
    with pytest.raises(InputError, match="does not fit float16"):
        half_state({"big": torch.tensor([1e6])})


def test_float16_storage_is_exact_for_float16_weights_and_half_the_size(tmp_path):
    import onnxruntime as ort

    from export.onnx_io import store_float16

    rng = np.random.default_rng(0)
    w = rng.normal(size=(64, 3, 3, 3)).astype(np.float16).astype(np.float32)  # float16 values
    x = helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 3, 16, 16])
    y = helper.make_tensor_value_info("y", TensorProto.FLOAT, None)
    graph = helper.make_graph([helper.make_node("Conv", ["x", "w"], ["y"], pads=[1, 1, 1, 1])], "g", [x], [y],
                              [numpy_helper.from_array(w, "w")])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])
    model.ir_version = 10
    plain = tmp_path / "plain.onnx"
    half = tmp_path / "half.onnx"
    onnx.save(model, plain)
    onnx.save(store_float16(onnx.load(plain)), half)
    assert [n.op_type for n in onnx.load(half).graph.node] == ["Cast", "Conv"]
    assert half.stat().st_size < 0.6 * plain.stat().st_size
    feed = {"x": rng.random((1, 3, 16, 16), dtype=np.float32)}
    a = ort.InferenceSession(str(plain), providers=["CPUExecutionProvider"]).run(None, feed)[0]
    b = ort.InferenceSession(str(half), providers=["CPUExecutionProvider"]).run(None, feed)[0]
    assert np.array_equal(a, b)
