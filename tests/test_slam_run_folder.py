"""A run folder holds one run: built beside OUT and moved into place at the
end; a complete earlier run is replaced only with --overwrite; an interrupted or failed run
leaves a folder marked as such, never a mix; evaluate refuses runs that did not complete."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from c3f_slam.cli.main import main
from c3f_slam.pipeline.slam import FragmentSlam

RUN = ["--set", "frames.max_frames=6", "--set", "fragments.min_correspondences=15", "--quiet"]


def _files(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


def _error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: "), err
    return err[0]


def _siblings(out: Path) -> list[str]:
    """Hidden staging / trash folders left beside OUT."""
    return sorted(p.name for p in out.parent.iterdir() if p.name.startswith(f".{out.name}."))


@pytest.fixture(scope="module")
def tiny_sequence(tmp_path_factory) -> Path:
    """128 px frames: enough correspondences to register and fuse a few frames."""
    from datamodules.synthetic.fixture import make_tiny_sequence

    return make_tiny_sequence(tmp_path_factory.mktemp("runfolder") / "seq", frames=8, size=128, seed=3)


@pytest.fixture()
def mesh_run(tiny_sequence, tmp_path) -> Path:
    """A complete run with a mesh."""
    out = tmp_path / "out"
    assert main(["run", str(tiny_sequence), "--out", str(out), *RUN]) == 0
    assert (out / "mesh.ply").is_file()
    return out


def test_complete_run_needs_overwrite(tiny_sequence, mesh_run, capsys):
    before = _files(mesh_run)
    assert main(["run", str(tiny_sequence), "--out", str(mesh_run), "--set", "fusion.enabled=false", *RUN]) == 2
    assert "--overwrite" in _error_line(capsys)
    assert _files(mesh_run) == before  # untouched
    assert _siblings(mesh_run) == []


def test_overwrite_replaces_the_whole_folder(tiny_sequence, mesh_run):
    """A rerun without a mesh (--set fusion.enabled=false) leaves no mesh of the earlier run beside its own files."""
    (mesh_run / "trajectory.png").write_bytes(b"an evaluate output of the earlier run")
    assert main(["run", str(tiny_sequence), "--out", str(mesh_run), "--set", "fusion.enabled=false", "--overwrite",
                 *RUN]) == 0
    names = set(_files(mesh_run))
    assert "mesh.ply" not in names and "trajectory.png" not in names
    assert json.loads((mesh_run / "summary.json").read_text())["config"]["fusion"]["enabled"] is False
    assert _siblings(mesh_run) == []


def test_a_folder_that_is_not_a_run_is_never_replaced(tiny_sequence, tmp_path, capsys):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("keep me")
    assert main(["run", str(tiny_sequence), "--out", str(out), "--overwrite", *RUN]) == 2
    assert "not a run folder" in _error_line(capsys)
    assert (out / "notes.txt").read_text() == "keep me" and _siblings(out) == []


def test_during_a_run_out_still_holds_the_previous_run(tiny_sequence, mesh_run, monkeypatch):
    """What a kill -9 at any moment before the end would leave: the earlier complete run."""
    before = _files(mesh_run)
    seen: list[bool] = []
    add = FragmentSlam.add

    def watching_add(self, frame):
        seen.append(_files(mesh_run) == before and len(_siblings(mesh_run)) == 1)
        return add(self, frame)

    monkeypatch.setattr(FragmentSlam, "add", watching_add)
    assert main(["run", str(tiny_sequence), "--out", str(mesh_run), "--overwrite", *RUN]) == 0
    assert seen and all(seen)


@pytest.mark.parametrize("exc, rc", [(RuntimeError("planted failure"), None), (KeyboardInterrupt(), 130)])
def test_a_failed_or_interrupted_run_is_marked_not_mixed(tiny_sequence, mesh_run, monkeypatch, capsys, exc, rc):
    """The folder then holds the partial run only (status error, frames done), and evaluate refuses it."""
    add = FragmentSlam.add

    def failing_add(self, frame):
        if frame.index >= 3:
            raise exc
        return add(self, frame)

    monkeypatch.setattr(FragmentSlam, "add", failing_add)
    args = ["run", str(tiny_sequence), "--out", str(mesh_run), "--overwrite", *RUN]
    if rc is None:
        with pytest.raises(RuntimeError, match="planted failure"):
            main(args)
    else:
        assert main(args) == rc
        assert "interrupted" in _error_line(capsys)
    summary = json.loads((mesh_run / "summary.json").read_text())
    assert summary["status"] == "error" and summary["frames"] == 4  # frames 0-3 read
    assert "mesh.ply" not in _files(mesh_run)  # nothing of the earlier run
    assert _siblings(mesh_run) == []
    monkeypatch.undo()
    assert main(["evaluate", str(mesh_run), "--gt", str(tiny_sequence)]) == 2
    assert "did not complete" in _error_line(capsys)
    # an incomplete run is replaced without --overwrite
    assert main(["run", str(tiny_sequence), "--out", str(mesh_run), *RUN]) == 0


# ---------------------------------------------------------------------- unreadable frames


def test_unreadable_frames_are_skipped_and_counted_up_to_a_limit(tiny_sequence, tmp_path, capsys):
    import shutil

    seq = tmp_path / "seq"
    shutil.copytree(tiny_sequence, seq)
    bad = sorted((seq / "rgb").iterdir())[3]
    bad.write_bytes(b"\x89PNG damaged")
    out = tmp_path / "ok"
    assert main(["run", str(seq), "--out", str(out), "--set", "fusion.enabled=false", *RUN]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "ok" and s["skipped_unreadable"] == 1 and s["frames"] == 6
    out0 = tmp_path / "strict"
    assert main(["run", str(seq), "--out", str(out0), "--set", "fusion.enabled=false", "--max-bad-frames", "0",
                 *RUN]) == 2
    line = _error_line(capsys)
    assert bad.name in line and "--max-bad-frames 0" in line
    s = json.loads((out0 / "summary.json").read_text())
    assert s["status"] == "error" and s["skipped_unreadable"] == 1 and s["frames"] == 4
