"""The recording effects inside the simulator (``SimParams.recording``): seeded, image-only (depth
and poses as without them), off = the frames as rendered, covered masks written and left out of
the training losses, ``--set recording.FIELD=VALUE`` on the command line."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from c3f_slam.io import Sequence
from datamodules.base import FrameTupleDataset, covered_of
from datamodules.config import FramesConfig, LoaderConfig, SplitConfig
from datamodules.sequence import C3FSequenceDataModule
from datamodules.synthetic.__main__ import main as cli_main
from datamodules.synthetic.fixture import make_tiny_sequence, tiny_params
from datamodules.synthetic.generate import read_recording
from datamodules.synthetic.recording import RecordingParams, video_codecs
from datamodules.synthetic.scene import build_scene, render_frames

FRAMES, SIZE = 4, 48
#: every per-frame effect on in every frame (strong enough to change every frame)
ALL_ON = {"recording.fluid_share": 1.0, "recording.bubbles_share": 1.0, "recording.bubbles_size": 0.08,
          "recording.specular_share": 1.0, "recording.gain_r": 1.15, "recording.gain_b": 0.85,
          "recording.falloff": 0.8, "recording.noise": 0.3, "recording.interlace_share": 0.5,
          "recording.jpeg_share": 1.0}
VIDEO = {"recording.video": "mp4v", "recording.video_chunk": 3} if "mp4v" in video_codecs() else {}


def _files(root: Path, folder: str) -> list[bytes]:
    return [p.read_bytes() for p in sorted((root / folder).glob("*.png"))]


def _rgb(root: Path) -> list[np.ndarray]:
    return [cv2.imread(str(p), cv2.IMREAD_COLOR)[..., ::-1] for p in sorted((root / "rgb").glob("*.png"))]


@pytest.fixture(scope="module")
def pair(tmp_path_factory) -> tuple[Path, Path]:
    """The same tiny sequence without and with every recording effect (and the video round trip)."""
    base = tmp_path_factory.mktemp("recording")
    off = make_tiny_sequence(base / "off", frames=FRAMES, size=SIZE, seed=3)
    on = make_tiny_sequence(base / "on", frames=FRAMES, size=SIZE, seed=3, **ALL_ON, **VIDEO)
    return off, on


def test_same_seed_same_bytes(pair, tmp_path):
    _, on = pair
    again = make_tiny_sequence(tmp_path / "again", frames=FRAMES, size=SIZE, seed=3, **ALL_ON, **VIDEO)
    for folder in ("rgb", "covered", "depth"):
        assert _files(again, folder) == _files(on, folder), folder
    for name in ("recording.json", "params.json", "poses.txt"):
        assert (again / name).read_bytes() == (on / name).read_bytes(), name
    other = make_tiny_sequence(tmp_path / "other", frames=FRAMES, size=SIZE, seed=4, **ALL_ON, **VIDEO)
    assert _files(other, "rgb") != _files(on, "rgb")


def test_effects_change_only_the_image(pair):
    off, on = pair
    assert _files(on, "depth") == _files(off, "depth")
    assert (on / "poses.txt").read_bytes() == (off / "poses.txt").read_bytes()
    assert (on / "camera.json").read_bytes() == (off / "camera.json").read_bytes()
    diffs = [np.abs(a.astype(int) - b).mean() for a, b in zip(_rgb(on), _rgb(off))]
    assert len(diffs) == FRAMES and min(diffs) > 1.0  # every frame changed
    record = read_recording(on)
    assert sorted(record) == list(range(FRAMES))
    assert all({"noise", "light", "jpeg"} <= set(r["effects"]) for r in record.values())
    assert all(r["covered"] > 0 for r in record.values())
    if VIDEO:
        assert all(r["effects"][-1] == "video" for r in record.values())
    params = json.loads((on / "params.json").read_text())["params"]
    assert params["recording"]["noise"] == 0.3 and "recording" not in json.loads(
        (off / "params.json").read_text())["params"]


def test_defaults_leave_the_rendered_frames(pair, tmp_path):
    """Off, the written frames are the renderer's output, and params.json has no recording group."""
    off, _ = pair
    assert not (off / "covered").exists() and not (off / "recording.json").exists()
    params = tiny_params(FRAMES, SIZE, 3)
    assert params.recording == RecordingParams() and not params.recording.active()
    rendered = [rgb for _, rgb, _ in render_frames(build_scene(params))]
    assert all(np.array_equal(a, b) for a, b in zip(_rgb(off), rendered, strict=True))
    # setting a field to its default value changes nothing either
    same = make_tiny_sequence(tmp_path / "same", frames=FRAMES, size=SIZE, seed=3, **{"recording.noise": 0.0})
    assert _files(same, "rgb") == _files(off, "rgb")
    assert (same / "params.json").read_bytes() == (off / "params.json").read_bytes()


def test_covered_masks_reach_the_batch(tmp_path):
    """Bubbles forced on: covered/ holds their pixels, and the batch's exclusion mask has them."""
    seq_dir = make_tiny_sequence(tmp_path / "data" / "bubbly", frames=FRAMES, size=SIZE, seed=5,
                                 **{"recording.bubbles_share": 1.0, "recording.bubbles_count": 6,
                                    "recording.bubbles_size": 0.1})
    masks = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in sorted((seq_dir / "covered").glob("*.png"))]
    assert len(masks) == FRAMES and all(m.shape == (SIZE, SIZE) for m in masks)
    assert all((m > 0).any() for m in masks) and set(np.unique(np.concatenate(masks))) <= {0, 255}
    seq = Sequence(seq_dir)
    covered = covered_of(seq, 1)
    assert np.array_equal(covered, masks[1] > 0)
    sample = FrameTupleDataset([seq], FramesConfig(size=None, specular=False))[0]  # centre = frame 1
    excluded = sample["specular"][1, 0].numpy()
    assert excluded[covered].all() and excluded.sum() == covered.sum()  # exactly the covered pixels
    # resized: any covered frame pixel under a network pixel leaves it out
    small = FrameTupleDataset([seq], FramesConfig(size=(24, 24), specular=False))[0]["specular"][1, 0].numpy()
    blocks = covered.reshape(24, 2, 24, 2).any(axis=(1, 3))
    assert np.array_equal(small, blocks)
    # without the covered/ folder the same frames leave nothing out
    bare = tmp_path / "bare"
    shutil.copytree(seq_dir, bare)
    shutil.rmtree(bare / "covered")
    assert not FrameTupleDataset([Sequence(bare)], FramesConfig(size=None, specular=False))[0]["specular"].any()
    # and through a data module's loader
    dm = C3FSequenceDataModule(str(tmp_path / "data"), split=SplitConfig(train=["bubbly"]),
                               frames=FramesConfig(size=None, specular=False), loader=LoaderConfig(batch_size=2))
    dm.setup("fit")
    batch = next(iter(dm.train_dataloader()))
    assert batch["specular"].dtype == torch.bool and bool(batch["specular"].any())


def test_repeated_frame_keeps_the_mask_it_shows(tmp_path):
    seq_dir = make_tiny_sequence(tmp_path / "rep", frames=6, size=SIZE, seed=2,
                                 **{"recording.bubbles_share": 1.0, "recording.persist_frames": 1,
                                    "nuisance.repeat_share": 0.6, "nuisance.border": "circle"})
    names = json.loads((seq_dir / "nuisances.json").read_text())
    repeats = [int(i) for i, n in names.items() if "repeat" in n]
    assert repeats, "seed 2 gives no repeat: pick another"
    tissue = cv2.imread(str(seq_dir / "tissue_mask.png"), cv2.IMREAD_GRAYSCALE) > 0
    for i in range(6):
        m = cv2.imread(str(seq_dir / "covered" / f"{i:06d}.png"), cv2.IMREAD_GRAYSCALE) > 0
        assert not (m & ~tissue).any()  # inside the border
        if i in repeats:
            prev = cv2.imread(str(seq_dir / "covered" / f"{i - 1:06d}.png"), cv2.IMREAD_GRAYSCALE)
            assert np.array_equal(m, prev > 0)


def test_set_on_the_command_line(tmp_path, capsys):
    out = tmp_path / "cli"
    base = ["generate", "--preset", "tiny", "--set", "path.frames=3", "--set", "camera.width=32",
            "--set", "camera.height=32", "--no-progress"]
    assert cli_main([*base, "--set", "recording.noise=0.45", "--set", "recording.video=none",
                     "--out", str(out)]) in (0, None)
    assert json.loads((out / "params.json").read_text())["params"]["recording"]["noise"] == 0.45
    assert all(r["effects"] == ["noise"] for r in read_recording(out).values())
    capsys.readouterr()
    try:
        code = cli_main([*base, "--set", "recording.noise=3", "--out", str(tmp_path / "bad")])
    except SystemExit as exc:  # usage errors (argparse)
        code = exc.code
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "recording.noise" in err
    assert not (tmp_path / "bad").exists()
