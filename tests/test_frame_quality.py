"""The frame-quality gate (c3f_slam.frames.quality) on synthetic frames made here: a smooth random
texture with lines and rings, seen through a 256 px window that slides about a pixel per frame.
Each cause is put into one frame of such a sequence and must be the frame's status; the sharp
frames around it, also JPEG-compressed or noisy, must all pass."""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from dataclasses import fields

import cv2
import numpy as np
import pytest

from c3f_core.errors import InputError
from c3f_slam.frames.quality import (
    BLURRED,
    COVERED,
    DARK,
    DUPLICATE,
    OK,
    QUALITY_CAUSES,
    WASHED_OUT,
    FrameQuality,
    FrameQualityConfig,
    FrameQualityGate,
)

SIZE = 256  # frame side, px


def texture(size: int = 768, seed: int = 0) -> np.ndarray:
    """RGB uint8 (size, size, 3): smooth noise at 3 scales, tissue-coloured, with lines and rings."""
    rng = np.random.default_rng(seed)
    t = np.zeros((size, size), np.float32)
    for cells, weight in ((6, 1.0), (24, 0.6), (96, 0.35)):
        noise = rng.random((cells, cells)).astype(np.float32)
        t += weight * cv2.resize(noise, (size, size), interpolation=cv2.INTER_CUBIC)
    t = (t - t.min()) / (t.max() - t.min())
    img = np.stack([70 + 150 * t, 35 + 80 * t, 30 + 60 * t], -1).astype(np.float32)
    for _ in range(40):
        x0, y0, x1, y1 = (int(v) for v in rng.integers(0, size, 4))
        cv2.line(img, (x0, y0), (x1, y1), (100.0, 40.0, 35.0), int(rng.integers(1, 4)), cv2.LINE_AA)
    for _ in range(30):
        cx, cy = (int(v) for v in rng.integers(0, size, 2))
        cv2.circle(img, (cx, cy), int(rng.integers(5, 40)), (230.0, 140.0, 120.0), int(rng.integers(1, 3)),
                   cv2.LINE_AA)
    return np.clip(img, 0, 255).astype(np.uint8)


TEXTURE = texture()


def view(x: float, y: float = 0.0, tex: np.ndarray = TEXTURE, size: int = SIZE) -> np.ndarray:
    """The size x size window of ``tex`` at (100 + x, 100 + y) px (sub-pixel: bilinear)."""
    shift = np.float32([[1, 0, -(100 + x)], [0, 1, -(100 + y)]])
    return cv2.warpAffine(tex, shift, (size, size), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


def jpeg(rgb: np.ndarray, quality: int = 70) -> np.ndarray:
    """``rgb`` encoded as JPEG at ``quality`` and decoded."""
    ok, data = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, quality])
    assert ok
    return cv2.cvtColor(cv2.imdecode(data, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)


def noisy(rgb: np.ndarray, rng: np.random.Generator, sigma: float = 3.0) -> np.ndarray:
    """``rgb`` with Gaussian sensor noise of ``sigma`` (0..255)."""
    return np.clip(rgb + rng.normal(0.0, sigma, rgb.shape), 0, 255).astype(np.uint8)


def gaussian_blur(rgb: np.ndarray) -> np.ndarray:
    return cv2.GaussianBlur(rgb, (0, 0), 2.0)


def motion_blur(rgb: np.ndarray) -> np.ndarray:
    """A 9 px streak along a diagonal (the scope moving during the exposure)."""
    return cv2.filter2D(rgb, -1, np.eye(9, dtype=np.float32) / 9)


def defocus(rgb: np.ndarray) -> np.ndarray:
    """A disc blur of radius 4 px (out of focus)."""
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (9, 9)).astype(np.float32)
    return cv2.filter2D(rgb, -1, disc / disc.sum())


def over_exposed(rgb: np.ndarray) -> np.ndarray:
    return np.clip(rgb * 3.0 + 100, 0, 255).astype(np.uint8)


def under_exposed(rgb: np.ndarray) -> np.ndarray:
    return (rgb * 0.12).astype(np.uint8)


def bubbles(rgb: np.ndarray, count: int = 150, seed: int = 0) -> np.ndarray:
    """``rgb`` under ``count`` small bubbles: a pale rim and a white highlight each."""
    rng = np.random.default_rng(seed)
    out = rgb.copy()
    h, w = rgb.shape[:2]
    for _ in range(count):
        cx, cy, r = int(rng.integers(0, w)), int(rng.integers(0, h)), int(rng.integers(5, 12))
        cv2.circle(out, (cx, cy), r, (235, 225, 215), 1, cv2.LINE_AA)
        cv2.circle(out, (cx - r // 3, cy - r // 3), max(1, r // 4), (255, 255, 255), -1, cv2.LINE_AA)
    return out


def moving(n: int, start: float = 0.0, step: float = 1.0) -> Iterator[np.ndarray]:
    """``n`` frames of the texture sliding ``step`` px right and step / 2 down per frame."""
    for k in range(n):
        yield view(start + step * k, 0.5 * step * k)


def run(gate: FrameQualityGate, frames) -> list[FrameQuality]:
    return [gate.assess(f) for f in frames]


def warmed_gate(frames: int = 20, cfg: FrameQualityConfig | None = None, step: float = 1.0) -> FrameQualityGate:
    """A gate that has accepted ``frames`` sharp frames (x = 0, step, ..)."""
    gate = FrameQualityGate(cfg)
    assert [q.status for q in run(gate, moving(frames, step=step))] == [OK] * frames
    return gate


# -- sharp sequences pass ---------------------------------------------------------------------

@pytest.mark.parametrize("variant", ["clean", "jpeg70", "noise", "noise+jpeg70"])
def test_a_sharp_slowly_moving_sequence_passes(variant):
    rng = np.random.default_rng(1)
    frames = []
    for f in moving(60):
        if "noise" in variant:
            f = noisy(f, rng)
        if "jpeg" in variant:
            f = jpeg(f)
        frames.append(f)
    qualities = run(FrameQualityGate(), frames)
    assert [q.status for q in qualities] == [OK] * 60
    assert all(q.sharpness_ratio is None for q in qualities[:5])
    assert all(q.sharpness_ratio is not None for q in qualities[5:])


def test_a_dark_lumen_and_a_saturated_red_channel_are_not_exposure_faults():
    gate = warmed_gate()
    lumen = view(20, 10)
    cv2.circle(lumen, (150, 120), 85, (12, 6, 5), -1, cv2.LINE_AA)  # a dark hole over ~1/3 of the view
    q = gate.assess(lumen)
    assert q.status == OK and 0.25 < q.dark_share < 0.5
    red = view(21, 10.5)
    red[:, :, 0] = np.clip(red[:, :, 0] * 2.0 + 20, 0, 255)  # lit mucosa: red saturates, the view is not white
    assert np.mean(red[:, :, 0] == 255) > 0.4
    q = gate.assess(red)
    assert q.status != WASHED_OUT and q.washed_share == 0.0


# -- each cause -------------------------------------------------------------------------------

@pytest.mark.parametrize("spoil, cause", [
    (gaussian_blur, BLURRED),
    (motion_blur, BLURRED),
    (defocus, BLURRED),
    (over_exposed, WASHED_OUT),
    (under_exposed, DARK),
    (bubbles, COVERED),
])
def test_a_spoiled_frame_is_flagged_with_its_cause(spoil: Callable[[np.ndarray], np.ndarray], cause: str):
    gate = warmed_gate()
    q = gate.assess(spoil(view(20, 10)))
    assert q.status == cause and q.status in QUALITY_CAUSES
    assert not q.usable
    assert gate.assess(view(21, 10.5)).status == OK  # the next sharp frame passes again


def test_blurred_measures():
    gate = warmed_gate()
    q = gate.assess(gaussian_blur(view(20, 10)))
    assert q.status == "blurred" and q.sharpness_ratio < FrameQualityConfig().blur_ratio
    sharp = gate.assess(view(21, 10.5))
    assert 0.7 < sharp.sharpness_ratio < 1.4


def test_the_first_frames_are_not_blurred_for_lack_of_a_reference():
    gate = FrameQualityGate()
    first = gate.assess(gaussian_blur(view(0)))
    assert first.status == OK and first.sharpness_ratio is None
    later = run(gate, moving(10, start=1))
    assert [q.status for q in later] == [OK] * 10
    assert gate.assess(gaussian_blur(view(11, 5))).status == BLURRED  # the median outvoted the first


def test_a_long_blurred_run_restarts_the_reference():
    """A change of content (a smooth close-up) is no blur: after reference_reset blurred frames in
    a row the reference restarts and the smooth frames pass."""
    gate = warmed_gate(cfg=FrameQualityConfig(reference_reset=10))
    smooth = cv2.GaussianBlur(TEXTURE, (0, 0), 3.0)
    measured = [gate.assess(view(20 + k, 10 + k / 2, tex=smooth)) for k in range(30)]
    assert [q.status for q in measured[:10]] == [BLURRED] * 10
    assert [q.status for q in measured[10:]] == [OK] * 20
    last = measured[-FrameQualityConfig().reference_frames:]
    assert gate.reference == pytest.approx(np.median([q.sharpness for q in last]))  # the new reference


# -- duplicates -------------------------------------------------------------------------------

@pytest.mark.parametrize("repeat", [
    lambda f: f.copy(),
    jpeg,
    lambda f: jpeg(f, 50),
    lambda f: noisy(f, np.random.default_rng(3), sigma=1.0),
], ids=["exact", "jpeg70", "jpeg50", "noise"])
def test_a_repeat_of_the_previous_frame_is_a_duplicate(repeat):
    gate = warmed_gate()
    previous = view(20, 10)
    assert gate.assess(previous).status == OK
    q = gate.assess(repeat(previous))
    assert q.status == DUPLICATE
    assert q.duplicate_motion < 0.3 and q.duplicate_distance < 1.0


def test_a_noisier_repeat_of_a_fast_moving_scope_is_a_duplicate_by_its_share_of_the_motion():
    """JPEG at quality 30 leaves more than the absolute noise level, but far less than the 6 px
    a frame moves here: a duplicate by the share of the accepted frames' median motion, and not
    without that criterion."""
    for share, expected in ((FrameQualityConfig().duplicate_motion_share, DUPLICATE), (0.0, OK)):
        gate = warmed_gate(cfg=FrameQualityConfig(duplicate_motion_share=share), step=6.0)
        previous = view(200, 100)
        assert gate.assess(previous).status == OK
        q = gate.assess(jpeg(previous, 30))
        assert q.duplicate_motion > FrameQualityConfig().duplicate_motion and q.status == expected


@pytest.mark.parametrize("shift", [(2.0, 0.0), (0.0, 3.0), (2.0, 2.0)])
def test_a_frame_moved_by_a_few_pixels_is_no_duplicate(shift):
    gate = warmed_gate()
    assert gate.assess(view(20, 10)).status == OK
    q = gate.assess(jpeg(view(20 + shift[0], 10 + shift[1])))
    assert q.status == OK
    assert q.duplicate_motion > 1.0


def test_slow_motion_adds_up_against_the_last_accepted_frame():
    """0.1 px per frame is below the compression-noise level, but a flagged frame does not move
    the reference: the motion adds up and every few frames one passes."""
    gate = warmed_gate()
    statuses = [gate.assess(view(20 + 0.1 * k, 10)).status for k in range(1, 41)]
    assert set(statuses) == {OK, DUPLICATE}
    run_length = max(len(r) for r in "".join("d" if s == DUPLICATE else "." for s in statuses).split("."))
    assert run_length <= 4
    assert statuses.count(OK) >= 8


def test_a_repeated_blurred_picture_counts_once_as_blurred():
    gate = warmed_gate()
    blurred = motion_blur(view(20, 10))
    statuses = [gate.assess(f).status for f in (blurred, jpeg(blurred), blurred, view(21, 10.5))]
    assert statuses == [BLURRED, DUPLICATE, DUPLICATE, OK]


def test_a_blurred_copy_of_the_accepted_frame_is_blurred():
    """A blur of a large frame changes little at 64 px, so a blurred copy of the accepted frame can
    be as close to it as a re-encode (here: a tolerance large enough for that); blurred comes
    first. A second blurred copy repeats the rejected picture: a duplicate."""
    gate = warmed_gate(cfg=FrameQualityConfig(duplicate_motion=2.0, duplicate_luma=5.0), step=3.0)
    accepted = view(60, 30)
    gate.assess(accepted)
    first, second = gate.assess(gaussian_blur(accepted)), gate.assess(gaussian_blur(accepted))
    assert first.duplicate_motion < 2.0 and (first.status, second.status) == (BLURRED, DUPLICATE)
    assert gate.assess(jpeg(accepted)).status == DUPLICATE


def test_a_repeat_after_a_flagged_frame_compares_with_the_last_accepted_frame():
    gate = warmed_gate()
    accepted = view(20, 10)
    gate.assess(accepted)
    assert gate.assess(under_exposed(view(21, 10))).status == DARK
    assert gate.assess(jpeg(accepted)).status == DUPLICATE


# -- the mask ---------------------------------------------------------------------------------

def octagon_mask(size: int = SIZE) -> np.ndarray:
    """The tissue of a scope image: an octagon, a black border around it."""
    c, r = size / 2, size * 0.47
    angles = np.deg2rad(22.5 + 45 * np.arange(8))
    corners = np.stack([c + r * np.cos(angles), c + r * np.sin(angles)], -1).round().astype(np.int32)
    mask = np.zeros((size, size), np.uint8)
    cv2.fillConvexPoly(mask, corners, 1)
    return mask.astype(bool)


def test_only_the_pixels_inside_the_mask_count():
    mask = octagon_mask()
    rng = np.random.default_rng(5)
    frames = list(moving(12))
    frames += [gaussian_blur(view(12, 6)), view(13, 6.5), view(13, 6.5), bubbles(view(14, 7)), view(15, 7.5),
               over_exposed(view(16, 8)), under_exposed(view(17, 8.5)), view(18, 9)]
    black, overlay = [], []
    for k, f in enumerate(frames):
        black.append(np.where(mask[..., None], f, 0).astype(np.uint8))
        outside = rng.integers(0, 256, f.shape).astype(np.uint8)
        outside[:30, :] = 255  # an on-screen banner, white, with changing text
        cv2.putText(outside, f"frame {k} 00:0{k % 10}", (5, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 2)
        overlay.append(np.where(mask[..., None], f, outside).astype(np.uint8))
    a = run(FrameQualityGate(mask=mask), black)
    b = run(FrameQualityGate(mask=mask.astype(np.uint8)), overlay)
    assert [q.as_dict() for q in a] == [q.as_dict() for q in b]
    assert [q.status for q in a[12:]] == [BLURRED, OK, DUPLICATE, COVERED, OK, WASHED_OUT, DARK, OK]
    # without the mask the banner is part of the picture: its changing text is no duplicate
    unmasked = run(FrameQualityGate(), [overlay[13], overlay[14]])
    assert unmasked[1].duplicate_distance > a[14].duplicate_distance


# -- determinism, output, settings --------------------------------------------------------------

def test_the_gate_is_deterministic_and_reset_forgets():
    frames = [*moving(15), gaussian_blur(view(15, 7.5)), view(16, 8), view(16, 8), bubbles(view(17, 8.5))]
    gate = FrameQualityGate()
    first = [q.as_dict() for q in run(gate, frames)]
    assert first == [q.as_dict() for q in run(FrameQualityGate(), frames)]
    gate.reset()
    assert first == [q.as_dict() for q in run(gate, frames)]


def test_as_dict_is_json_and_names_every_measure():
    gate = FrameQualityGate()
    first, second = gate.assess(view(0)), gate.assess(view(1))
    d = json.loads(json.dumps(second.as_dict()))
    assert set(d) == {f.name for f in fields(FrameQuality)}
    assert d["status"] == OK and d["duplicate_distance"] > 0
    assert first.as_dict()["duplicate_distance"] is None and first.as_dict()["sharpness_ratio"] is None


def test_disabled_gate_passes_every_frame_but_still_measures():
    gate = FrameQualityGate(FrameQualityConfig(enabled=False))
    qualities = run(gate, [*moving(8), under_exposed(view(8)), view(9), view(9)])
    assert {q.status for q in qualities} == {OK}
    assert qualities[8].dark_share == 1.0 and qualities[10].duplicate_distance == 0.0


@pytest.mark.parametrize("field, value", [
    ("enabled", "yes"),
    ("thumb_size", 16),
    ("duplicate_size", 4),
    ("duplicate_size", 200),
    ("reference_frames", 0),
    ("min_reference", 0),
    ("min_reference", 20),
    ("blur_ratio", 0.0),
    ("blur_ratio", 1.5),
    ("reference_reset", 0),
    ("dark_level", -1.0),
    ("dark_share", 0.0),
    ("washed_level", 300.0),
    ("washed_share", 2.0),
    ("duplicate_motion", -0.1),
    ("duplicate_luma", -1.0),
    ("highlight_contrast", 256.0),
    ("highlight_level", -5.0),
    ("covered_share", 0.0),
])
def test_the_config_refuses_bad_values(field, value):
    with pytest.raises(InputError, match=rf"frames\.quality\.{field}\b"):
        FrameQualityConfig(**{field: value})


def test_bad_frames_and_masks_are_refused():
    gate = FrameQualityGate()
    with pytest.raises(InputError, match="RGB uint8"):
        gate.assess(np.zeros((64, 64), np.uint8))
    with pytest.raises(InputError, match="RGB uint8"):
        gate.assess(np.zeros((64, 64, 3), np.float32))
    with pytest.raises(InputError, match="mask"):
        FrameQualityGate(mask=np.zeros((64, 64), bool))
    with pytest.raises(InputError, match="mask"):
        FrameQualityGate(mask=np.zeros((64, 64, 3), bool))
    with pytest.raises(InputError, match="64x48"):
        FrameQualityGate(mask=np.ones((48, 64), bool)).assess(view(0))


def test_small_and_odd_frame_sizes():
    """Frames smaller than the thumbnail are used whole; odd sizes lose at most a few edge pixels."""
    for w, h in ((48, 40), (333, 251)):
        gate = FrameQualityGate()
        frames = [cv2.resize(view(k, k / 2, size=400), (w, h), interpolation=cv2.INTER_AREA) for k in range(0, 40, 4)]
        assert [q.status for q in run(gate, frames)] == [OK] * len(frames)
        assert gate.assess(frames[-1].copy()).status == DUPLICATE


# -- in a run -----------------------------------------------------------------------------------

def test_a_run_skips_the_simulators_spoiled_frames_by_cause_and_keeps_one_map(tmp_path):
    from c3f_slam.config import preset as slam_preset
    from c3f_slam.pipeline import run_slam
    from datamodules.synthetic.fixture import make_tiny_sequence
    from datamodules.synthetic.nuisances import read_nuisances

    seq = make_tiny_sequence(tmp_path / "seq", frames=40, size=128, seed=4,
                             **{"nuisance.motion_blur_share": 0.15, "nuisance.motion_blur_px": 12,
                                "nuisance.repeat_share": 0.15, "nuisance.washed_out_share": 0.1})
    truth = read_nuisances(seq)
    cfg = slam_preset("colon", fragments={"min_correspondences": 15}, coverage={"enabled": False},
                      checks={"enabled": False})
    s = run_slam(seq, tmp_path / "out", cfg, progress=False)
    log = (tmp_path / "out" / "frame_log.csv").read_text().splitlines()
    assert log[0] == "index,timestamp,outcome" and len(log) == 41
    outcome = {int(row.split(",")[0]): row.split(",")[2] for row in log[1:]}
    expect = {"motion_blur": "blurred", "repeat": "duplicate", "washed_out": "washed_out"}
    for cause in expect.values():
        assert s[f"skipped_{cause}"] > 0
    flagged = [i for i, what in outcome.items() if what in expect.values()]
    right = [i for i in flagged if outcome[i] in {expect[n] for n in truth.get(i, []) if n in expect}]
    assert len(right) >= 0.8 * len(flagged)  # each flag names a nuisance the frame has
    spoiled = [i for i, names in truth.items() if any(n in expect for n in names)]
    assert sum(outcome[i] != "extended" and outcome[i] != "keyframe" for i in spoiled) >= 0.7 * len(spoiled)
    assert s["registered_share_of_usable"] >= 0.9 and len(s["components"]) == 1


def highlights(rgb: np.ndarray, count: int = 40, seed: int = 0) -> np.ndarray:
    """``rgb`` with ``count`` large soft specular highlights (saturated white blobs of 6-16 px)."""
    rng = np.random.default_rng(seed)
    blobs = np.zeros(rgb.shape[:2], np.float32)
    h, w = blobs.shape
    for _ in range(count):
        centre = (int(rng.integers(0, w)), int(rng.integers(0, h)))
        axes = (int(rng.integers(6, 17)), int(rng.integers(3, 9)))
        cv2.ellipse(blobs, centre, axes, float(rng.uniform(0, 180)), 0, 360, 1.0, -1)
    alpha = np.clip(cv2.GaussianBlur(blobs, (0, 0), 1.5) * 1.5, 0, 1)[..., None]
    return (rgb * (1 - alpha) + 255 * alpha).astype(np.uint8)


def test_a_sharp_view_full_of_highlights_is_not_blurred_but_its_blurred_copy_is():
    """Large highlights carry their edges into the coarser octave: measured with them, a sharp wet
    view reads as blurred (the control); left out (the default), it passes, and blur still shows."""
    frame = highlights(view(20.0, 10.0))
    control = warmed_gate(cfg=FrameQualityConfig(blur_highlight_level=255.0))
    assert control.assess(frame).status == BLURRED
    assert warmed_gate().assess(frame).status == OK
    assert warmed_gate().assess(highlights(gaussian_blur(view(20.0, 10.0)))).status == BLURRED
