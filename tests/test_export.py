"""ONNX export: the CLI path (fit -> saved config + checkpoint -> export), parity with
PyTorch on frames the export never saw, metadata, DCN, ContraFeat, and bad input.

Exports take ~10 s each on CPU, so one module-scoped DepthNet export serves several tests.
"""

import json
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch

from c3f_core.errors import InputError
from c3f_models import ContraFeat, DepthNet
from c3f_models.cli import main
from c3f_models.contrafeat.config import ContraFeatNetworkConfig
from c3f_models.depth.config import DepthNetworkConfig
from c3f_slam.frames.preprocess import prepare_network_input
from c3f_slam.io import Sequence
from c3f_slam.models.metadata import SCHEMA_VERSION, ModelMetadata
from export import ParityError, export_model
from export import exporter as exporter_mod

ROOT = Path(__file__).resolve().parents[1]
SIZE = 64
TOL = 1e-4
ONE_SCALE = DepthNetworkConfig(num_scales=1)
CONTRA_16 = ContraFeatNetworkConfig(descriptor_dim=16, fpn_channels=16, stem_channels=8, head_channels=16)


def _session(path: Path) -> ort.InferenceSession:
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1
    return ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])


def _metadata(path: Path) -> ModelMetadata:
    props = {p.key: p.value for p in onnx.load(str(path), load_external_data=False).metadata_props}
    return ModelMetadata.from_props(props, str(path))


def _frame(seq_dir: Path, i: int, size: int = SIZE) -> torch.Tensor:
    """(1, 3, size, size) frame pre-processed as in training."""
    seq = Sequence(seq_dir)
    rgb, _, _ = prepare_network_input(seq.read_rgb(i), seq.camera, crop=None, size=(size, size), specular=True)
    return torch.from_numpy(np.ascontiguousarray(rgb)).permute(2, 0, 1)[None].float() / 255.0


@pytest.fixture(scope="module")
def depth_export(sim_dataset, tmp_path_factory):
    """One step of DepthNet small through the CLI, then ``export`` with the run's config.yaml."""
    root = tmp_path_factory.mktemp("export_run")
    common = ["--trainer.default_root_dir", str(root), "--trainer.logger.init_args.save_dir", str(root),
              "--trainer.enable_progress_bar", "false"]
    main(["fit", "--config", str(ROOT / "configs/trainer/cpu_smoke.yaml"), "--config",
          str(ROOT / "configs/depthnet/small.yaml"), "--data.data_dir", str(sim_dataset),
          "--data.frames.size", f"[{SIZE}, {SIZE}]", "--data.loader.batch_size", "2", "--trainer.max_steps", "1",
          *common])
    run = root / "tb" / "version_0"
    out = root / "exported"
    main(["export", "--config", str(run / "config.yaml"), "--ckpt_path", str(run / "checkpoints" / "last.ckpt"),
          "--output_dir", str(out)])
    return run, out


@pytest.mark.e2e
def test_cli_export_writes_files_with_metadata(depth_export):
    run, out = depth_export
    assert sorted(p.name for p in out.iterdir()) == ["depthnet.onnx", "export.json", "posenet.onnx"]
    depth, pose = _metadata(out / "depthnet.onnx"), _metadata(out / "posenet.onnx")
    assert (depth.kind, pose.kind) == ("depth", "pose")
    assert depth.schema_version == SCHEMA_VERSION and depth.opset == 18
    assert depth.preprocessing.size == (SIZE, SIZE) and depth.preprocessing.specular_inpaint
    assert depth.outputs[0]["name"] == "depth" and depth.outputs[0]["units"] == "m"
    assert depth.depth["min_depth"] == pytest.approx(0.001) and depth.depth["max_depth"] == pytest.approx(0.3)
    assert depth.training_config["model"]["init_args"]["network"]["encoder_layers"] == 18
    assert depth.training_config["data"]["init_args"]["frames"]["size"] == [SIZE, SIZE]
    assert depth.checkpoint["sha256"] == exporter_mod.sha256(run / "checkpoints" / "last.ckpt")
    assert 0 <= depth.parity["max_abs_diff"] <= TOL and depth.parity["frames"] >= 2
    model = onnx.load(str(out / "depthnet.onnx"))
    assert model.producer_name == "c3fusion"
    assert not any(t.data_location == onnx.TensorProto.EXTERNAL for t in model.graph.initializer)


@pytest.mark.e2e
@pytest.mark.parametrize("subcommand", ["export", "test"])
def test_checkpoint_with_flat_options_is_refused(depth_export, tmp_path, capsys, subcommand):
    """A checkpoint saved before the model options were grouped (flat hyper-parameters) is refused
    with one line naming the file, before LightningCLI would apply its options."""
    run, _ = depth_export
    new = torch.load(run / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=True)
    assert {"network", "loss", "optim", "evaluation"} <= set(new["hyper_parameters"])  # the grouped form
    old = tmp_path / "flat.ckpt"
    flat = {"_class_path": "c3f_models.depth.module.DepthNet", "encoder_layers": 18, "dcn": False, "lambda_dc": 0.1,
            "lr": 1e-4, "_instantiator": "lightning.pytorch.cli.instantiate_module"}
    torch.save({"state_dict": new["state_dict"], "hyper_parameters": flat, "global_step": 1}, old)
    args = ["--output_dir", str(tmp_path / "out")] if subcommand == "export" else ["--trainer.logger", "false"]
    with pytest.raises(SystemExit) as exc:
        main([subcommand, "--config", str(run / "config.yaml"), "--ckpt_path", str(old), *args])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: --ckpt_path: {old} holds model options DepthNet no longer "
                                               "takes (dcn, encoder_layers, lambda_dc, lr; saved before")
    assert not (tmp_path / "out").exists()


@pytest.mark.e2e
def test_depth_parity_on_unseen_frames_and_sizes(depth_export, sim_dataset):
    run, out = depth_export
    net = DepthNet.load_from_checkpoint(run / "checkpoints" / "last.ckpt", map_location="cpu").eval()
    sess = _session(out / "depthnet.onnx")
    seq = sorted(p for p in sim_dataset.iterdir() if p.is_dir())[-1]
    image = torch.cat([_frame(seq, 1), _frame(seq, 4)])  # batch of 2: dynamic batch
    with torch.no_grad():
        expected = net(image).numpy()
    got = sess.run(None, {"image": image.numpy()})[0]
    assert got.shape == expected.shape == (2, 1, SIZE, SIZE)
    np.testing.assert_allclose(got, expected, rtol=0, atol=TOL)
    assert got.min() >= 0.001 - 1e-6 and got.max() <= 0.3 + 1e-6  # metres, within the trained range
    wide = torch.nn.functional.interpolate(image[:1], size=(SIZE, 96), mode="bilinear")  # dynamic H/W
    with torch.no_grad():
        np.testing.assert_allclose(sess.run(None, {"image": wide.numpy()})[0], net(wide).numpy(), rtol=0, atol=TOL)


@pytest.mark.e2e
def test_pose_graph_is_rigid_and_matches_torch(depth_export, sim_dataset):
    run, out = depth_export
    net = DepthNet.load_from_checkpoint(run / "checkpoints" / "last.ckpt", map_location="cpu").eval()
    seq = sorted(p for p in sim_dataset.iterdir() if p.is_dir())[0]
    a, b = _frame(seq, 2), _frame(seq, 3)
    T = _session(out / "posenet.onnx").run(None, {"image_a": a.numpy(), "image_b": b.numpy()})[0]
    with torch.no_grad():
        np.testing.assert_allclose(T, net.pose_net(a, b).numpy(), rtol=0, atol=TOL)
    R = T[0, :3, :3].astype(np.float64)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-5)
    np.testing.assert_allclose(T[0, 3], [0, 0, 0, 1], atol=1e-7)


@pytest.mark.e2e
def test_export_rejects_wrong_kind_and_wrong_architecture(tmp_path, tiny_sequence):
    contra = tmp_path / "contrafeat.ckpt"
    contra_model = ContraFeat({"descriptor_dim": 8, "fpn_channels": 8, "stem_channels": 4})
    torch.save({"state_dict": contra_model.state_dict()}, contra)
    with pytest.raises(InputError, match=r"--ckpt_path: .*contrafeat.ckpt is a ContraFeat checkpoint, "
                                         r"but the config's model is DepthNet"):
        export_model(DepthNet(ONE_SCALE), contra, tmp_path / "out", frames=tiny_sequence)
    r34 = tmp_path / "r34.ckpt"
    torch.save({"state_dict": DepthNet(DepthNetworkConfig(encoder_layers=34, num_scales=1)).state_dict()}, r34)
    with pytest.raises(InputError, match="does not fit the model in the config"):
        export_model(DepthNet(DepthNetworkConfig(encoder_layers=18, num_scales=1)), r34, tmp_path / "out",
                     frames=tiny_sequence)
    with pytest.raises(InputError, match="--ckpt_path: file not found"):
        export_model(DepthNet(ONE_SCALE), tmp_path / "missing.ckpt", tmp_path / "out", frames=tiny_sequence)
    garbage = tmp_path / "garbage.ckpt"
    garbage.write_bytes(b"not a checkpoint")
    with pytest.raises(InputError, match="is not a torch checkpoint"):
        export_model(DepthNet(ONE_SCALE), garbage, tmp_path / "out", frames=tiny_sequence)
    with pytest.raises(InputError, match="--frames: sequence folder not found"):
        export_model(DepthNet(ONE_SCALE), r34, tmp_path / "out", frames=tmp_path / "nowhere")
    with pytest.raises(InputError, match="model: Linear does not say what it exports"):
        export_model(torch.nn.Linear(2, 2), r34, tmp_path / "out", frames=tiny_sequence)
    assert not (tmp_path / "out").exists()


@pytest.mark.e2e
def test_checkpoint_of_another_model_class_is_refused_by_the_cli(depth_export, tmp_path, capsys):
    """A ContraFeat checkpoint given with a DepthNet config: LightningCLI would swap in the
    checkpoint's class and export a ContraFeat; refused in one line, nothing written."""
    run, _ = depth_export
    cf = ContraFeat(CONTRA_16)
    other = tmp_path / "contrafeat.ckpt"
    hparams = {"_class_path": "c3f_models.contrafeat.module.ContraFeat", **dict(cf.hparams),
               "_instantiator": "lightning.pytorch.cli.instantiate_module"}
    torch.save({"state_dict": cf.state_dict(), "hyper_parameters": hparams, "global_step": 1}, other)
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as exc:
        main(["export", "--config", str(run / "config.yaml"), "--ckpt_path", str(other), "--output_dir", str(out)])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: --ckpt_path: {other} holds a ContraFeat"), err
    assert "c3f_models.depth.module.DepthNet" in err[0] and not out.exists()


@pytest.mark.e2e
def test_contrafeat_export_parity_and_unit_descriptors(tmp_path, tiny_sequence):
    """Both graphs: the dense map, and the keypoint graph equal to that map sampled at the same
    keypoints by the runtime's rule (recorded in its parity entry), which the runtime then prefers."""
    from c3f_slam.matching import sample_descriptor_map
    from c3f_slam.models import DescriptorModel
    from export.graphs import parity_keypoints

    torch.manual_seed(0)
    model = ContraFeat(CONTRA_16)
    ckpt = tmp_path / "cf.ckpt"
    torch.save({"state_dict": model.state_dict()}, ckpt)
    fresh = ContraFeat(CONTRA_16)
    path, kp_path = export_model(fresh, ckpt, tmp_path / "out", frames=tiny_sequence, num_frames=2)
    meta, kp_meta = _metadata(path), _metadata(kp_path)
    assert (path.name, meta.kind, meta.descriptor_dim, meta.sampling) == ("contrafeat.onnx", "descriptors", 16, "dense")
    assert (kp_path.name, kp_meta.kind, kp_meta.descriptor_dim, kp_meta.sampling) == (
        "contrafeat_kp.onnx", "descriptors", 16, "keypoints")
    assert meta.preprocessing.size == (64, 64) and meta.parity["max_abs_diff"] <= TOL
    assert kp_meta.parity["max_abs_diff"] <= TOL and kp_meta.parity["dense_sampling"]["max_abs_diff"] <= 1e-5
    assert kp_meta.parity["dense_sampling"]["keypoints"] == 64 and kp_meta.checkpoint == meta.checkpoint
    assert [i["name"] for i in kp_meta.inputs] == ["image", "keypoints"]
    assert kp_meta.outputs[0]["shape"] == ["batch", "keypoints", 16]
    listed = json.loads((tmp_path / "out" / "export.json").read_text())["files"]
    assert {n: e["descriptor_sampling"] for n, e in listed.items()} == {"contrafeat.onnx": "dense",
                                                                         "contrafeat_kp.onnx": "keypoints"}
    image = _frame(tiny_sequence, 5)
    got = _session(path).run(None, {"image": image.numpy()})[0]
    with torch.no_grad():
        np.testing.assert_allclose(got, model.eval()(image).numpy(), rtol=0, atol=TOL)
    np.testing.assert_allclose(np.linalg.norm(got, axis=1), 1.0, atol=1e-5)
    # another image size and another number of keypoints than the export's (dynamic axes)
    wide = torch.nn.functional.interpolate(torch.cat([image, _frame(tiny_sequence, 2)]), size=(64, 96),
                                           mode="bilinear")
    points = parity_keypoints(2, 64, 96, count=100, seed=3)
    sampled = _session(kp_path).run(None, {"image": wide.numpy(), "keypoints": points.numpy()})[0]
    maps = _session(path).run(None, {"image": wide.numpy()})[0]
    want = np.stack([sample_descriptor_map(m, p) for m, p in zip(maps, points.numpy())])
    assert sampled.shape == (2, 100, 16)
    np.testing.assert_allclose(sampled, want, rtol=0, atol=1e-5)
    runtime = DescriptorModel(path, prefer_keypoints=True)
    assert runtime.onnx.path == kp_path and runtime.keypoint_file == "used"


@pytest.mark.e2e
def test_export_selects_descriptor_graphs_by_name(tmp_path, tiny_sequence):
    """``descriptors_kp`` alone: the keypoint file (still checked against the dense graph, which
    is not written); a name the model lacks lists the names it has."""
    ckpt = tmp_path / "cf.ckpt"
    torch.save({"state_dict": ContraFeat(CONTRA_16).state_dict()}, ckpt)
    with pytest.raises(InputError, match=r"--graphs: depth: this model exports \['descriptors', 'descriptors_kp'\]"):
        export_model(ContraFeat(CONTRA_16), ckpt, tmp_path / "bad", frames=tiny_sequence, graphs=["depth"])
    (path,) = export_model(ContraFeat(CONTRA_16), ckpt, tmp_path / "out", frames=tiny_sequence, num_frames=1,
                           graphs=["descriptors_kp"])
    assert path.name == "contrafeat_kp.onnx" and sorted(p.name for p in path.parent.iterdir()) == [
        "contrafeat_kp.onnx", "export.json"]
    assert _metadata(path).parity["dense_sampling"]["max_abs_diff"] <= 1e-5


def test_keypoint_sampler_is_the_training_and_runtime_rule():
    """The keypoint graph's sampler = the training sampler per item = the runtime's NumPy rule,
    on the parity keypoints (corners, borders, outside the map, sub-pixel)."""
    from c3f_models.contrafeat.graphs import sample_keypoints
    from c3f_models.contrafeat.network import sample_descriptors
    from c3f_slam.matching import sample_descriptor_map
    from export.graphs import parity_keypoints

    torch.manual_seed(0)
    maps = torch.nn.functional.normalize(torch.randn(2, 16, 20, 24), dim=1)
    points = parity_keypoints(2, 20, 24, count=40)
    u, v = points[..., 0], points[..., 1]
    assert (u < 0).any() and (u > 23).any() and (v < 0).any() and (v > 19).any()  # outside: clamped
    assert ((u == 0) & (v == 0)).any(dim=1).all() and ((u == 23) & (v == 19)).any(dim=1).all()  # corners
    assert (points != points.round()).any()  # sub-pixel positions
    got = sample_keypoints(maps, points)
    assert got.shape == (2, 40, 16)
    for b in range(2):
        np.testing.assert_allclose(got[b].numpy(), sample_descriptors(maps[b], points[b]).numpy(), atol=1e-6)
        np.testing.assert_allclose(got[b].numpy(), sample_descriptor_map(maps[b].numpy(), points[b].numpy()),
                                   atol=1e-6)


def test_check_keypoint_sampling_detects_another_map(tmp_path):
    from export.graphs import parity_keypoints
    from export.parity import check_keypoint_sampling
    from tests import onnx_fixtures as fx

    images, points = torch.rand(2, 3, 32, 32), parity_keypoints(2, 32, 32)
    dense = fx.descriptor_graph(dim=8, dynamic=True)
    entry = check_keypoint_sampling(fx.keypoint_descriptor_graph(dim=8, dynamic=True), dense, images, points)
    assert entry["max_abs_diff"] <= 1e-5 and (entry["frames"], entry["keypoints"]) == (2, 64)
    with pytest.raises(ParityError, match="contrafeat_kp.onnx: the keypoint graph differs from the dense graph"):
        check_keypoint_sampling(fx.keypoint_descriptor_graph(dim=8, dynamic=True, seed=1), dense, images, points,
                                name="contrafeat_kp.onnx")


@pytest.mark.e2e
def test_dcn_depth_exports_with_opset_19_and_runs(tmp_path, tiny_sequence):
    torch.manual_seed(0)
    model = DepthNet(DepthNetworkConfig(dcn=True, num_scales=1))
    with torch.no_grad():  # non-zero offsets, so the deformable sampling is really exercised
        for m in model.depth_net.modules():
            if type(m).__name__ == "DeformConv":
                m.offset.weight.normal_(0, 0.01)
    ckpt = tmp_path / "dcn.ckpt"
    torch.save({"state_dict": model.state_dict()}, ckpt)
    written = export_model(DepthNet(DepthNetworkConfig(dcn=True, num_scales=1)), ckpt, tmp_path / "out",
                           frames=tiny_sequence, num_frames=2, dynamic_size=False)
    depth = next(p for p in written if p.name == "depthnet.onnx")
    assert _metadata(depth).opset == 19 and not _metadata(depth).dynamic_size
    assert any(n.op_type == "DeformConv" for n in onnx.load(str(depth)).graph.node)
    image = _frame(tiny_sequence, 3)
    with torch.no_grad():
        np.testing.assert_allclose(_session(depth).run(None, {"image": image.numpy()})[0], model.eval()(image).numpy(),
                                   rtol=0, atol=TOL)


def test_failed_parity_writes_nothing_and_keeps_earlier_files(tmp_path, tiny_sequence, monkeypatch):
    ckpt = tmp_path / "d.ckpt"
    torch.save({"state_dict": DepthNet(ONE_SCALE).state_dict()}, ckpt)
    out = tmp_path / "out"
    out.mkdir()
    (out / "depthnet.onnx").write_bytes(b"earlier export")

    def bad_parity(module, model, inputs, input_names, tolerance=1e-4, name="graph", criterion="max_abs"):
        raise ParityError(f"{name}: onnxruntime differs from PyTorch by 0.5 (max abs)")

    monkeypatch.setattr(exporter_mod, "to_onnx", lambda *a, **k: onnx.ModelProto())  # the export itself is tested above
    monkeypatch.setattr(exporter_mod, "check_parity", bad_parity)
    with pytest.raises(ParityError, match="depthnet.onnx: onnxruntime differs"):
        export_model(DepthNet(ONE_SCALE), ckpt, out, frames=tiny_sequence, num_frames=2)
    assert (out / "depthnet.onnx").read_bytes() == b"earlier export"
    assert sorted(p.name for p in out.iterdir()) == ["depthnet.onnx"]


@pytest.mark.e2e
def test_export_writes_only_the_chosen_graphs(tmp_path, tiny_sequence):
    """``graphs``: DepthNet without PoseNet; a kind the model lacks is refused before anything is written."""
    ckpt = tmp_path / "d.ckpt"
    torch.save({"state_dict": DepthNet(ONE_SCALE).state_dict()}, ckpt)
    out = tmp_path / "out"
    with pytest.raises(InputError, match=r"--graphs: descriptors: this model exports \['depth', 'pose'\]"):
        export_model(DepthNet(ONE_SCALE), ckpt, out, frames=tiny_sequence, num_frames=1, graphs=["descriptors"])
    assert not out.exists()
    written = export_model(DepthNet(ONE_SCALE), ckpt, out, frames=tiny_sequence, num_frames=1, graphs=["depth"])
    assert [p.name for p in written] == ["depthnet.onnx"] and not (out / "posenet.onnx").exists()
    assert list(json.loads((out / "export.json").read_text())["files"]) == ["depthnet.onnx"]


@pytest.mark.e2e
def test_check_parity_detects_a_different_graph(tmp_path):
    from export.onnx_io import to_onnx
    from export.parity import check_parity

    torch.manual_seed(0)
    a = torch.nn.Sequential(torch.nn.Conv2d(3, 4, 3, padding=1))
    b = torch.nn.Sequential(torch.nn.Conv2d(3, 4, 3, padding=1))
    x = torch.rand(2, 3, 64, 64)
    proto = to_onnx(a, (x,), ("image",), "out", 18)
    assert check_parity(a, proto, (x,), ("image",), TOL).max_abs_diff <= 1e-5
    with pytest.raises(ParityError, match="above the tolerance"):
        check_parity(b, proto, (x,), ("image",), TOL)


@pytest.mark.e2e
def test_runtime_loader_reads_the_export(depth_export, sim_dataset):
    """c3f_slam.models on the real export: same depth as PyTorch, pre-processing included."""
    from c3f_slam.models import DepthModel, PoseModel

    run, out = depth_export
    net = DepthNet.load_from_checkpoint(run / "checkpoints" / "last.ckpt", map_location="cpu").eval()
    seq_dir = sorted(p for p in sim_dataset.iterdir() if p.is_dir())[0]
    seq = Sequence(seq_dir)
    model = DepthModel(out / "depthnet.onnx", threads=1)
    depth, view = model.predict_network(seq.read_rgb(2), seq.camera)
    with torch.no_grad():
        np.testing.assert_allclose(depth, net(_frame(seq_dir, 2))[0, 0].numpy(), rtol=0, atol=TOL)
    assert view.size == (SIZE, SIZE)
    full = model.predict(seq.read_rgb(2), seq.camera)
    assert full.shape == (seq.camera.height, seq.camera.width) and full.min() > 0
    T = PoseModel(out / "posenet.onnx", threads=1).predict(seq.read_rgb(2), seq.read_rgb(3), seq.camera)
    with torch.no_grad():
        np.testing.assert_allclose(T, net.pose_net(_frame(seq_dir, 2), _frame(seq_dir, 3))[0].numpy(), atol=TOL)
    with pytest.raises(InputError, match="is a pose model, expected a depth model"):
        DepthModel(out / "posenet.onnx")


@pytest.mark.e2e
def test_export_records_the_metric_scale_of_the_training_data(depth_export):
    """depth.metric_scale = median over training frames of median(true) / median(predicted),
    recomputed here through the runtime (onnxruntime, its own pre-processing) on the training
    sequences of the recorded data settings; the SLAM runtime uses it by default."""
    import cv2

    from c3f_slam.frames.preprocess import center_crop_resize
    from c3f_slam.models import DepthModel
    from c3f_slam.pipeline.frontend import ModelDepth
    from datamodules.sequence import C3FSequenceDataModule

    _, out = depth_export
    meta = _metadata(out / "depthnet.onnx")
    assert meta.depth["metric_scale"] > 0 and meta.depth["metric_scale_frames"] > 0
    assert "training sequences" in meta.depth["metric_scale_source"]
    dm = C3FSequenceDataModule(**meta.training_config["data"]["init_args"])
    model = DepthModel(out / "depthnet.onnx", threads=1)
    ratios = []
    for path in dm.split()["train"]:
        seq = Sequence(path)
        for i in np.unique(np.linspace(0, len(seq) - 1, num=min(8, len(seq))).round().astype(int)):
            pred, view = model.predict_network(seq.read_rgb(int(i)), seq.camera)
            gt, _ = center_crop_resize(seq.read_depth(int(i)), seq.camera, None, view.size, cv2.INTER_NEAREST)
            ok = (gt > 0) & (pred > 0)
            ratios.append(np.median(gt[ok]) / np.median(pred[ok]))
    assert len(ratios) == meta.depth["metric_scale_frames"]
    assert meta.depth["metric_scale"] == pytest.approx(float(np.median(ratios)), rel=1e-3)
    assert model.metric_scale == meta.depth["metric_scale"]
    assert ModelDepth(model, Sequence(dm.split()["train"][0]).camera).scale_source == "model metadata"
