"""The sequence data-module base: tuples, pre-processing, splits, bad input."""

import cv2
import numpy as np
import pytest
import torch
from numpy.testing import assert_allclose

from c3f_core.errors import InputError
from c3f_slam import geometry as g
from c3f_slam.frames.preprocess import specular_mask
from c3f_slam.io import Sequence
from datamodules.base import FrameTupleDataset, split_names
from datamodules.config import FramesConfig, LoaderConfig, SplitConfig, TupleSamplingConfig
from datamodules.sequence import C3FSequenceDataModule
from tests.scenes import plane_sequence


def test_triplets_with_stride(plane_dataset):
    seq = Sequence(plane_dataset / "plane0")
    ds = FrameTupleDataset([seq], FramesConfig(size=None), TupleSamplingConfig(stride=2))
    # 6 frames, offsets (-2, 0, 2): centres 2 and 3
    assert len(ds) == 2
    s = ds[0]
    assert s["frame_index"].tolist() == [0, 2, 4]
    assert s["image"].shape == (3, 3, 48, 48) and s["image"].dtype == torch.float32
    assert 0.0 <= float(s["image"].min()) and float(s["image"].max()) <= 1.0
    assert s["depth"].shape == (3, 1, 48, 48) and s["pose"].shape == (3, 4, 4)
    assert_allclose(s["pose"][1].numpy(), seq.pose(2), atol=1e-6)


def test_crop_resize_keeps_geometry(plane_dataset):
    """After crop+resize, the depth of a pixel back-projects to the same world point."""
    seq = Sequence(plane_dataset / "plane1")
    ds = FrameTupleDataset([seq], FramesConfig(crop=(40, 40), size=(20, 20)))
    s = ds[0]
    K = s["K"].numpy().astype(np.float64)
    depth = s["depth"][1, 0].numpy()
    T = s["pose"][1].numpy().astype(np.float64)
    pts_w = g.transform_points(T, g.backproject(depth, K).reshape(-1, 3))
    # the plane of tests/scenes.py is z_w = 0.05 m (nearest-neighbour depth keeps it exact)
    assert_allclose(pts_w[:, 2], 0.05, atol=2e-4)


def test_specular_mask_covers_highlight_plus_dilation():
    img = np.full((64, 64, 3), 100, np.uint8)
    img[30:34, 30:34] = 255
    mask = specular_mask(img)
    assert mask[30:34, 30:34].all()
    # 13-px elliptical kernel: grows by 6 px on each side, not more
    assert mask[32, 24] and mask[32, 39] and not mask[32, 23] and not mask[32, 40]
    assert not specular_mask(np.full((8, 8, 3), 200, np.uint8)).any()  # Y = 200 < 229.5


def test_specular_pixels_inpainted_in_batch(tmp_path):
    root = plane_sequence(tmp_path / "s", frames=3, size=48)
    p = root / "rgb" / "000001.png"
    img = cv2.imread(str(p))
    img[20:24, 20:24] = 255
    cv2.imwrite(str(p), img)
    s = FrameTupleDataset([Sequence(root)], FramesConfig(size=None))[0]
    assert s["specular"][1, 0, 20:24, 20:24].all()
    assert float(s["image"][1, :, 20:24, 20:24].max()) < 0.95  # the highlight is gone


def test_split_names_whole_sequences():
    tr, va, te = split_names([f"s{i}" for i in range(10)], 0.1, 0.2)
    assert (tr, va, te) == ([f"s{i}" for i in range(7)], ["s7"], ["s8", "s9"])
    tr, va, te = split_names(["a", "b", "c"], 0.1, 0.2)
    assert (tr, va, te) == (["a"], ["b"], ["c"])
    tr, va, te = split_names(["a"], 0.1, 0.2)
    assert (tr, va, te) == (["a"], [], [])


def test_datamodule_batches(plane_dataset):
    dm = C3FSequenceDataModule(str(plane_dataset), frames=FramesConfig(size=(32, 32)),
                               loader=LoaderConfig(batch_size=2))
    dm.setup("fit")
    batch = next(iter(dm.train_dataloader()))
    assert batch["image"].shape == (2, 3, 3, 32, 32)
    assert batch["K"].shape == (2, 3, 3) and batch["K"][0, 0, 0] > 0
    assert len(dm.datasets["train"].sequences) == 1 and len(dm.datasets["val"].sequences) == 1


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda root: None, "folder not found"),
        (lambda root: root.mkdir(), "no project-layout sequences found"),
        (lambda root: plane_sequence(root / "short", frames=2), "2 frame"),
    ],
)
def test_bad_data_dir(tmp_path, make, match):
    root = tmp_path / "data"
    make(root)
    dm = C3FSequenceDataModule(str(root), frames=FramesConfig(size=None))
    with pytest.raises(InputError, match=match):
        dm.setup("fit")


def test_unknown_split_name(plane_dataset):
    dm = C3FSequenceDataModule(str(plane_dataset), split=SplitConfig(train=["plane0", "nope"]))
    with pytest.raises(InputError, match=r"data.split.train: unknown sequence 'nope'"):
        dm.setup("fit")


def test_nan_depth_rejected(tmp_path):
    root = plane_sequence(tmp_path / "s", frames=3, size=16)
    seq = Sequence(root)
    orig = seq.read_depth
    seq.read_depth = lambda i: np.full_like(orig(i), np.nan)
    with pytest.raises(InputError, match="NaN"):
        FrameTupleDataset([seq], FramesConfig(size=None))[0]




def test_a_scope_border_named_by_camera_json_is_filled_and_left_out_of_the_losses(plane_dataset, tmp_path):
    """A sequence whose camera.json names a tissue mask (a video's, written by the ingest) is seen
    as the runtime sees it: no black border in the network input, and the border in the mask of
    pixels the losses leave out."""
    import json
    import shutil

    seq_dir = shutil.copytree(plane_dataset / "plane0", tmp_path / "scoped")
    seq = Sequence(seq_dir)
    h, w = seq.camera.height, seq.camera.width
    tissue = np.zeros((h, w), np.uint8)
    cv2.circle(tissue, (w // 2, h // 2), int(0.45 * min(w, h)), 255, -1)
    for p in seq.rgb_paths:  # the border black, as a scope's
        img = cv2.imread(str(p))
        img[tissue == 0] = 0
        cv2.imwrite(str(p), img)
    cv2.imwrite(str(seq_dir / "tissue_mask.png"), tissue)
    bare = FrameTupleDataset([Sequence(seq_dir)], FramesConfig(size=None))[0]
    cam = json.loads((seq_dir / "camera.json").read_text())
    (seq_dir / "camera.json").write_text(json.dumps({**cam, "tissue_mask": "tissue_mask.png"}))
    scoped = FrameTupleDataset([Sequence(seq_dir)], FramesConfig(size=None))[0]
    outside = torch.from_numpy(tissue == 0)
    assert float(bare["image"][1][:, outside].max()) == 0.0  # without the mask: the black border
    assert float(scoped["image"][1][:, outside].mean()) > 0.1  # with it: the tissue continued
    assert scoped["specular"][:, 0][:, outside].all() and not bare["specular"][:, 0][:, outside].any()
    inside = torch.from_numpy(cv2.erode(tissue, np.ones((5, 5), np.uint8)) > 0)
    assert torch.equal(scoped["image"][1][:, inside], bare["image"][1][:, inside])
