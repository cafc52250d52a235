"""The sequence data module trains directly on simulator output (split by whole sequence)."""

import numpy as np
import torch

from c3f_slam import geometry as g
from datamodules.config import FramesConfig, LoaderConfig, SplitConfig
from datamodules.sequence import C3FSequenceDataModule


def test_datamodule_over_simulated_sequences(sim_dataset):
    dm = C3FSequenceDataModule(str(sim_dataset), split=SplitConfig(val_fraction=0.34, test_fraction=0.34),
                               frames=FramesConfig(size=(32, 32)), loader=LoaderConfig(batch_size=2))
    dm.setup("fit")
    dm.setup("test")
    names = {k: {s.name for s in ds.sequences} for k, ds in dm.datasets.items()}
    assert names == {"train": {"sim0"}, "val": {"sim1"}, "test": {"sim2"}}
    batch = next(iter(dm.train_dataloader()))
    assert batch["image"].shape == (2, 3, 3, 32, 32)
    depth = batch["depth"][0, 1, 0].numpy()
    assert (depth > 0).all() and float(depth.max()) < 0.2  # inside a colon: every ray hits the wall within 20 cm
    # ground truth is consistent after the resize: the centre pixel of frame t lands on the
    # same world point when seen from t+1 (static scene, exact depth)
    K = batch["K"][0].numpy().astype(np.float64)
    T_t, T_n = (batch["pose"][0, k].numpy().astype(np.float64) for k in (1, 2))
    p_w = g.transform_points(T_t, g.backproject(depth, K)[16:17, 16])
    uv, z = g.project(g.transform_points(g.invert_pose(T_n), p_w), K)
    u, v = np.round(uv[0]).astype(int)
    assert 0 <= u < 32 and 0 <= v < 32
    d_next = batch["depth"][0, 2, 0].numpy()[v, u]
    assert abs(d_next - z[0]) / z[0] < 0.1
    assert torch.isfinite(batch["image"]).all()
