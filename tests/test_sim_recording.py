"""Recording effects for simulated frames (datamodules.synthetic.recording) and the look sampler
(datamodules.synthetic.randomize): seeded, off = identity, image-only, masks, bad values."""

from __future__ import annotations

import inspect
from dataclasses import fields

import numpy as np
import pytest

from c3f_core.errors import InputError
from datamodules.synthetic import recording as rec
from datamodules.synthetic.randomize import LookRanges, sample_look, set_args, split_items
from datamodules.synthetic.recording import RecordingChain, RecordingParams, recording_from_items

H, W = 40, 48
#: each effect alone, on in every frame
ALONE = {
    "fluid": {"fluid_share": 1.0, "fluid_cover": 0.3},
    "bubbles": {"bubbles_share": 1.0, "bubbles_count": 5, "bubbles_size": 0.08},
    "specular": {"specular_share": 1.0},
    "light": {"gain_r": 1.2, "gain_b": 0.8, "falloff": 1.0, "uneven": 0.5},
    "noise": {"noise": 0.5, "noise_grain_px": 0.7},
    "interlace": {"interlace_share": 1.0, "interlace_px": 3.0},
    "jpeg": {"jpeg_share": 1.0, "jpeg_quality_min": 30, "jpeg_quality_max": 60},
}


def frames(n: int = 4) -> list[np.ndarray]:
    """Textured, moving test frames (uint8 RGB)."""
    y, x = np.mgrid[0:H, 0:W].astype(np.float32)
    out = []
    for i in range(n):
        r = 120 + 60 * np.sin((x + 2 * i) / 5.0) * np.cos(y / 7.0)
        g = 70 + 30 * np.cos((x - i) / 9.0)
        b = 60 + 20 * np.sin(y / 4.0 + i)
        out.append(np.clip(np.stack([r, g, b], axis=2), 0, 255).astype(np.uint8))
    return out


@pytest.mark.parametrize("name", list(ALONE))
def test_effect_seeded_deterministic_and_changes_frame(name):
    fs = frames()
    a = RecordingChain(RecordingParams(**ALONE[name]), W, H, seed=3).apply(2, fs[2])
    b = RecordingChain(RecordingParams(**ALONE[name]), W, H, seed=3).apply(2, fs[2])
    c = RecordingChain(RecordingParams(**ALONE[name]), W, H, seed=4).apply(2, fs[2])
    assert np.array_equal(a.rgb, b.rgb) and a.names == b.names == (name,)
    assert not np.array_equal(a.rgb, fs[2])
    if name not in ("light",):  # the light's only random draw is the sequence's direction
        assert not np.array_equal(a.rgb, c.rgb)


def test_off_is_identity_and_inactive():
    p = RecordingParams()
    assert not p.active() and p.per_frame_effects() == ()
    fs = frames()
    out = RecordingChain(p, W, H, seed=1).apply_sequence(fs)
    for f, o in zip(fs, out):
        assert np.array_equal(f, o.rgb) and o.names == () and not o.covered.any() and not o.specular.any()


def test_image_only_no_depth_anywhere():
    """No function or method of the module takes or returns depth or a pose."""
    names = [rec.light, rec.sensor_noise, rec.interlace, rec.jpeg, rec.video_roundtrip, rec.fluid_layer,
             rec.bubble_layer, rec.highlight_layer, RecordingChain.apply, RecordingChain.apply_sequence]
    for fn in names:
        params = inspect.signature(fn).parameters
        assert not any("depth" in p or "pose" in p for p in params), fn.__name__
    assert {f.name for f in fields(rec.RecordingFrame)} == {"rgb", "covered", "specular", "names"}


@pytest.mark.parametrize("name,mask", [("fluid", "covered"), ("bubbles", "covered"), ("specular", "specular")])
def test_masks_cover_every_changed_pixel(name, mask):
    fs = frames()
    chain = RecordingChain(RecordingParams(**ALONE[name]), W, H, seed=5)
    hits = 0
    for i, f in enumerate(fs):
        out = chain.apply(i, f)
        m = getattr(out, mask)
        changed = (out.rgb != f).any(axis=2)
        assert not (changed & ~m).any()  # nothing changed outside the mask
        hits += int(m.sum())
    assert hits > 0


def test_tissue_mask_keeps_overlays_inside():
    fs = frames()
    tissue = np.zeros((H, W), bool)
    tissue[5:35, 6:40] = True
    p = RecordingParams(**ALONE["fluid"], **ALONE["bubbles"], **ALONE["specular"])
    for i, f in enumerate(fs):
        out = RecordingChain(p, W, H, seed=2).apply(i, f, tissue)
        assert np.array_equal(out.rgb[~tissue], f[~tissue])
        assert not (out.covered & ~tissue).any() and not (out.specular & ~tissue).any()


def test_frame_independent_of_number_of_frames_and_order():
    p = RecordingParams(**{k: v for d in ALONE.values() for k, v in d.items()}, gain_jitter=0.05, persist_frames=3)
    fs = frames(7)
    long = RecordingChain(p, W, H, seed=9).apply_sequence(fs)
    short = RecordingChain(p, W, H, seed=9).apply_sequence(fs[:4])
    single = RecordingChain(p, W, H, seed=9).apply(3, fs[3])
    for a, b in zip(long[:4], short):
        assert np.array_equal(a.rgb, b.rgb) and np.array_equal(a.covered, b.covered)
    assert np.array_equal(long[3].rgb, single.rgb)


def test_changing_one_share_leaves_other_effects():
    fs = frames()
    a = RecordingChain(RecordingParams(noise=0.4, fluid_share=1.0), W, H, seed=1).apply(1, fs[1])
    b = RecordingChain(RecordingParams(noise=0.4, fluid_share=1.0, interlace_share=0.0, jpeg_share=0.0),
                       W, H, seed=1).apply(1, fs[1])
    assert np.array_equal(a.rgb, b.rgb)


@pytest.mark.skipif("mp4v" not in rec.video_codecs(), reason="this OpenCV cannot encode mp4v")
def test_video_roundtrip_chunks_independent_of_length():
    fs = frames(6)
    p = RecordingParams(video="mp4v", video_chunk=3)
    long = RecordingChain(p, W, H, seed=0).apply_sequence(fs)
    short = RecordingChain(p, W, H, seed=0).apply_sequence(fs[:4])
    assert all(f.names == ("video",) for f in long)
    assert any(not np.array_equal(o.rgb, f) for o, f in zip(long, fs))  # lossy
    for a, b in zip(long[:3], short[:3]):  # the first chunk is complete in both
        assert np.array_equal(a.rgb, b.rgb)
    err = np.mean([np.abs(o.rgb.astype(float) - f).mean() for o, f in zip(long, fs)])
    assert err < 30  # a round trip, not garbage


def test_light_and_noise_behave_physically():
    flat = np.full((H, W, 3), 128, np.uint8)
    warm = rec.light(flat, (1.3, 1.0, 0.7))
    assert warm[..., 0].mean() > 128 > warm[..., 2].mean()
    field = rec.illumination(W, H, 1.0, 0.0, 0.0)
    assert field[H // 2, W // 2] > field[0, 0] and field.max() <= 1.0
    rng = np.random.default_rng(0)
    dark, bright = np.full((H, W, 3), 20, np.uint8), np.full((H, W, 3), 200, np.uint8)
    nd = rec.sensor_noise(dark, 1.0, 0.0, 0.0, rng).astype(float) - 20
    nb = rec.sensor_noise(bright, 1.0, 0.0, 0.0, rng).astype(float) - 200
    assert nd.std() > 1.0 and nb.std() > 1.0
    assert np.allclose(nd[..., 0], nd[..., 1], atol=1)  # chroma 0: the channels share the noise


def test_interlace_moves_only_odd_rows():
    f = frames()[0]
    out = rec.interlace(f, 3.0, 0.0)
    assert np.array_equal(out[0::2], f[0::2]) and not np.array_equal(out[1::2], f[1::2])


@pytest.mark.parametrize("field,value", [("noise", 1.5), ("gain_r", 0.1), ("video", "h265"), ("persist_frames", 0),
                                         ("jpeg_quality_min", 101), ("fluid_cover", float("nan")),
                                         ("bubbles_count", 2.5)])
def test_bad_value_names_the_field(field, value):
    with pytest.raises(InputError, match=f"recording.{field}"):
        RecordingParams(**{field: value})


def test_items_parsed_and_bad_items_named():
    p = recording_from_items(["recording.noise=0.25", "appearance.hue=3", "recording.video=mp4v"])
    assert p.noise == 0.25 and p.video == "mp4v"
    with pytest.raises(InputError, match="recording.noise"):
        recording_from_items(["recording.noise=lots"])
    with pytest.raises(InputError, match="recording.nosie"):
        recording_from_items({"nosie": 1})
    with pytest.raises(InputError, match="recording.jpeg_quality_min"):
        recording_from_items({"jpeg_quality_min": 90, "jpeg_quality_max": 80})


def test_sample_look_seeded_and_valid():
    a, b, c = sample_look(5), sample_look(5), sample_look(6)
    assert a == b and a != c
    keys = [i.split("=")[0] for i in a]
    assert len(keys) == len(set(keys)) and all(i.count("=") == 1 for i in a)
    sim, recs = split_items(a)
    assert recs and all(i.startswith("recording.") for i in recs) and not any(i.startswith("recording.") for i in sim)
    recording_from_items(recs)  # valid RecordingParams
    assert set_args(a)[0::2] == ("--set",) * len(a)
    lo, hi = LookRanges().hue
    hues = [float(dict(i.split("=") for i in sample_look(s))["appearance.hue"]) for s in range(20)]
    assert all(lo <= h <= hi for h in hues) and len(set(hues)) == 20


def test_sample_look_fixed_range_and_independent_fields():
    fixed = LookRanges(hue=(12.0, 12.0))
    d = dict(i.split("=") for i in sample_look(3, fixed))
    d0 = dict(i.split("=") for i in sample_look(3))
    assert float(d["appearance.hue"]) == 12.0
    assert d["appearance.saturation"] == d0["appearance.saturation"]  # other fields keep their draws
    with pytest.raises(InputError, match="look.hue"):
        LookRanges(hue=(5.0, 1.0))
    with pytest.raises(InputError, match="look.borders"):
        LookRanges(borders=("hexagon",))


def test_sample_look_valid_for_the_simulator():
    """The simulator's own groups accept the sampled items (the dotted-path setter of the project)."""
    from c3f_core.settings import set_path
    from datamodules.synthetic.params import SimParams

    for seed in range(10):
        p = SimParams()
        for item in split_items(sample_look(seed))[0]:
            key, value = item.split("=", 1)
            p = set_path(p, key, value)
        if hasattr(p, "validate"):
            p.validate()
