"""onnxruntime execution providers of the runtime's models (``run --providers``): unknown and
unavailable names refused in one line before the run folder is touched, CPU given explicitly
the same as the default, the providers used recorded in summary.json, and the IO-binding path
(what a CUDA session runs) giving the plain run's outputs."""

from __future__ import annotations

import json

import numpy as np
import onnxruntime as ort
import pytest

from c3f_core.errors import InputError
from c3f_slam.cli.main import main
from c3f_slam.models import OnnxModel
from c3f_slam.models.session import check_providers
from tests import onnx_fixtures as fx

CPU = "CPUExecutionProvider"


def _cli_error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: "), err
    return err[0]


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    d = tmp_path_factory.mktemp("provider_models")
    size, crop = (32, 32), (56, 56)
    return fx.depth_model(d / "depth.onnx", size, crop), fx.descriptor_model(d / "feat.onnx", size, crop)


def test_check_providers():
    assert check_providers(CPU) == (CPU,) and check_providers([CPU]) == (CPU,)
    cases = {"": "give comma-separated onnxruntime provider names", f"{CPU},": "give comma-separated",
             f"{CPU},{CPU}": f"{CPU} is given twice", "FastExecutionProvider": "'FastExecutionProvider' is not an "
             "onnxruntime execution provider"}
    for value, expected in cases.items():
        with pytest.raises(InputError) as exc:
            check_providers(value)
        assert "\n" not in str(exc.value) and str(exc.value).startswith("--providers: ") and expected in str(exc.value)


def test_unknown_provider_is_one_line_and_touches_nothing(tiny_sequence, models, tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["run", str(tiny_sequence), "--feature-model", str(models[1]), "--providers",
                 f"CUDAExecutoinProvider,{CPU}", "--out", str(out), "--quiet"]) == 2
    line = _cli_error(capsys)
    assert line.startswith("error: --providers: 'CUDAExecutoinProvider' is not an onnxruntime execution provider")
    assert not out.exists()


@pytest.mark.skipif("CUDAExecutionProvider" in ort.get_available_providers(), reason="this build has CUDA")
def test_unavailable_provider_is_one_line(tiny_sequence, models, tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["run", str(tiny_sequence), "--depth-model", str(models[0]), "--providers",
                 f"CUDAExecutionProvider,{CPU}", "--out", str(out), "--quiet"]) == 2
    line = _cli_error(capsys)
    assert "--providers: CUDAExecutionProvider is not available in this onnxruntime build (available: " in line
    assert CPU in line and not out.exists()


def test_cpu_given_explicitly_is_the_default(tiny_sequence, models, tmp_path):
    runs = {}
    for name, extra in (("default", []), ("cpu", ["--providers", CPU])):
        out = tmp_path / name
        assert main(["run", str(tiny_sequence), "--depth-model", str(models[0]), "--feature-model", str(models[1]),
                     "--out", str(out), "--set", "fragments.min_correspondences=15", "--set", "fusion.enabled=false",
                     "--quiet", *extra]) == 0
        runs[name] = out
    a, b = (json.loads((runs[k] / "summary.json").read_text()) for k in ("default", "cpu"))
    assert a["models"]["depth"]["providers"] == b["models"]["descriptors"]["providers"] == [CPU]
    assert a["registered_frames"] == b["registered_frames"] >= 1
    assert (runs["default"] / "trajectory.txt").read_bytes() == (runs["cpu"] / "trajectory.txt").read_bytes()


def test_io_binding_gives_the_plain_run_outputs(models):
    """The path a CUDA session takes (bound inputs and outputs), here bound on the CPU."""
    model = OnnxModel(models[1], providers=[CPU])
    assert model.providers == (CPU,) and not model.io_binding
    x = np.random.default_rng(0).random((2, 3, 32, 32), dtype=np.float32)
    plain = model.run({"image": x})["descriptors"]
    model.io_binding = True
    bound = model.run({"image": x})["descriptors"]
    assert bound.shape == (2, 8, 32, 32)
    np.testing.assert_array_equal(bound, plain)
