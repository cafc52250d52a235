"""Ctrl-C in every command line: one ``error: interrupted ...`` line, exit status 130,
and no partial output that looks complete. Ctrl-C is a KeyboardInterrupt raised by a
monkeypatched function."""

from pathlib import Path
from types import SimpleNamespace

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _interrupt(*args, **kwargs):
    raise KeyboardInterrupt


def _one_error(capsys) -> str:
    errors = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(errors) >= 1 and errors[-1].startswith("error: interrupted"), errors
    assert sum(line.startswith("error:") for line in errors) == 1, errors
    return errors[-1]


@pytest.mark.e2e
def test_validate_interrupted(plane_dataset, tmp_path, monkeypatch, capsys):
    from c3f_models.cli import main
    from c3f_models.depth.module import DepthNet

    monkeypatch.chdir(ROOT)
    monkeypatch.setattr(DepthNet, "validation_step", _interrupt)
    with pytest.raises(SystemExit) as exc:
        main(["validate", "--config", "configs/trainer/cpu_smoke.yaml", "--config", "configs/depthnet/small.yaml",
              "--data.data_dir", str(plane_dataset), "--data.frames.size", "[32, 32]",
              "--trainer.default_root_dir", str(tmp_path), "--trainer.logger.init_args.save_dir", str(tmp_path),
              "--trainer.enable_progress_bar", "false"])
    assert exc.value.code == 130
    assert _one_error(capsys) == "error: interrupted during validate; its results are incomplete, nothing was saved"


def test_export_interrupted_keeps_the_earlier_export_whole(tmp_path, monkeypatch):
    """Ctrl-C while the second graph is written: the earlier export (graphs + export.json) is as
    it was, and no staging folder is left beside it."""
    import export.exporter as exporter

    out = tmp_path / "exported"
    out.mkdir()
    earlier = {"depthnet.onnx": b"old depth", "posenet.onnx": b"old pose", "export.json": b"{}"}
    for name, data in earlier.items():
        (out / name).write_bytes(data)
    written = []

    def write_onnx(proto, meta, path):
        if written:
            raise KeyboardInterrupt
        Path(path).write_bytes(b"new")
        written.append(path)
        return Path(path)

    monkeypatch.setattr(exporter, "write_onnx", write_onnx)
    meta = SimpleNamespace(kind="depth", opset=18, parity={}, sampling=None, precision="float32")
    staged = [(SimpleNamespace(file_name=name), None, meta) for name in ("depthnet.onnx", "posenet.onnx")]
    with pytest.raises(KeyboardInterrupt):
        exporter._write_export(staged, out, SimpleNamespace(created="now", checkpoint={}))
    assert {p.name: p.read_bytes() for p in out.iterdir()} == earlier
    assert sorted(p.name for p in tmp_path.iterdir()) == ["exported"]
    monkeypatch.setattr(exporter, "write_onnx", lambda proto, meta, path: Path(path).write_bytes(b"new") and Path(path))
    exporter._write_export(staged, out, SimpleNamespace(created="now", checkpoint={}))
    assert (out / "depthnet.onnx").read_bytes() == b"new" and (out / "export.json").read_bytes() != b"{}"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["exported"]


@pytest.mark.e2e
def test_export_cli_interrupted(monkeypatch, capsys, tmp_path):
    from c3f_models import cli

    monkeypatch.setattr(cli.C3FCLI, "_run_subcommand", _interrupt)
    monkeypatch.chdir(ROOT)
    with pytest.raises(SystemExit) as exc:
        cli.main(["export", "--config", "configs/trainer/cpu_smoke.yaml", "--config", "configs/depthnet/small.yaml",
                  "--data.data_dir", str(tmp_path), "--trainer.logger", "false", "--output_dir", str(tmp_path / "x")])
    assert exc.value.code == 130
    assert _one_error(capsys) == "error: interrupted"


@pytest.mark.parametrize("argv,target,expected", [
    (["generate", "--preset", "seq1", "--out", "OUT"], "datamodules.synthetic.generate.generate_sequence",
     "error: interrupted; no sequence was written"),
    (["contact-sheet", "SEQ", "--out", "OUT/sheet.png"], "datamodules.synthetic.contact_sheet.make_contact_sheet",
     "error: interrupted; no contact sheet was written"),
])
def test_simulator_cli_interrupted(argv, target, expected, tmp_path, monkeypatch, capsys):
    from datamodules.synthetic.__main__ import main

    monkeypatch.setattr(target, _interrupt)
    argv = [a.replace("OUT", str(tmp_path / "out")).replace("SEQ", str(tmp_path)) for a in argv]
    assert main(argv) == 130
    assert _one_error(capsys) == expected
    assert not (tmp_path / "out").exists()


def test_datamodules_convert_interrupted(tmp_path, monkeypatch, capsys):
    from datamodules.__main__ import main

    monkeypatch.setattr("datamodules.convert.convert", _interrupt)
    assert main(["convert", "uts", str(tmp_path), "--out", str(tmp_path / "out"), "--no-progress"]) == 130
    assert _one_error(capsys) == "error: interrupted"


@pytest.mark.parametrize("argv,target", [
    (["evaluate", "OUT", "--gt", "GT"], "c3f_slam.pipeline.run_evaluation.evaluate_run"),
    (["inspect", "MODEL"], "c3f_slam.models.OnnxModel"),
])
def test_slam_cli_interrupted(argv, target, tmp_path, monkeypatch, capsys):
    from c3f_slam.cli.main import main

    monkeypatch.setattr(target, _interrupt)
    assert main([str(tmp_path / a) if a.isupper() else a for a in argv]) == 130
    assert _one_error(capsys) == "error: interrupted"
