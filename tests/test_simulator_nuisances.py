"""Nuisances of real recordings in the simulator (datamodules.synthetic.nuisances): the scope's
border and its tissue mask, burned-in overlay and clock, motion blur, defocus, wash-out and
repeated frames; seeded, ground truth kept exact, and off by default (files unchanged)."""

from __future__ import annotations

import filecmp
import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from c3f_core.errors import InputError
from c3f_core.settings import set_path, tree_from_mapping
from c3f_slam.io import Sequence, SequenceWriter
from datamodules.synthetic import make_tiny_sequence, tiny_params
from datamodules.synthetic.__main__ import main as cli_main
from datamodules.synthetic.nuisances import (
    OVERLAY_GREY,
    NuisanceChain,
    clock_text,
    read_nuisances,
    tissue_mask,
)
from datamodules.synthetic.params import NuisanceParams, SimParams
from datamodules.synthetic.scene import build_scene, render_frames

SIZE, FRAMES, SEED = 64, 8, 2
#: every per-frame nuisance, each in about half of the frames
ALL_ON = {"border": "circle", "border_scale": 1.05, "motion_blur_share": 0.5, "defocus_share": 0.5,
          "washed_out_share": 0.5, "repeat_share": 0.5}


@pytest.fixture(scope="module")
def clean(tmp_path_factory) -> Path:
    """A tiny sequence without nuisances."""
    return make_tiny_sequence(tmp_path_factory.mktemp("nuis") / "clean", frames=FRAMES, size=SIZE, seed=SEED)


@pytest.fixture(scope="module")
def frames(clean) -> list[tuple[np.ndarray, np.ndarray]]:
    """(rgb, depth) of the clean sequence's frames, the input of the chains below."""
    seq = Sequence(clean)
    return [(seq.read_rgb(i), seq.read_depth(i)) for i in range(len(seq))]


@pytest.fixture(scope="module")
def noisy(clean, tmp_path_factory) -> Path:
    """The same sequence with every nuisance, made through the command line (--config, then --set)."""
    root = tmp_path_factory.mktemp("nuis")
    params = root / "params.json"
    params.write_text(json.dumps(tiny_params(frames=FRAMES, size=SIZE, seed=SEED).to_dict()))
    out = root / "noisy"
    argv = ["generate", "--config", str(params), "--out", str(out), "--no-progress"]
    for key, value in ALL_ON.items():
        argv += ["--set", f"nuisance.{key}={value}"]
    assert cli_main(argv) == 0
    return out


def _run(frames, fps: float = 30.0, seed: int = SEED, **options) -> list:
    chain = NuisanceChain(NuisanceParams(**options), SIZE, SIZE, fps, seed)
    return [chain.apply(i, rgb, depth) for i, (rgb, depth) in enumerate(frames)]


def _sharpness(rgb: np.ndarray) -> float:
    """Laplacian variance of the grey image (inside a 4 px margin)."""
    lap = cv2.Laplacian(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY).astype(np.float64), cv2.CV_64F)
    return float(lap[4:-4, 4:-4].var())


# ---------------------------------------------------------------------- defaults


def test_defaults_are_off_and_leave_the_sequence_as_rendered(clean, tmp_path):
    """With the defaults the files are those of the frames as rendered, written without the
    nuisance code (SequenceWriter on render_frames), and no truth file or nuisance group is added."""
    assert not SimParams().nuisance.active()
    p = tiny_params(frames=FRAMES, size=SIZE, seed=SEED)
    scene = build_scene(p)
    ref = tmp_path / "ref"
    writer = SequenceWriter(ref, scene.camera)
    for i, rgb, depth in render_frames(scene):
        writer.write_frame(i, rgb, depth)
    writer.finish(scene.path.poses, np.arange(FRAMES) / p.path.fps)
    names = ["camera.json", "poses.txt"] + [f"{d}/{i:06d}.png" for d in ("rgb", "depth") for i in range(FRAMES)]
    _, mismatch, errors = filecmp.cmpfiles(clean, ref, names, shallow=False)
    assert not mismatch and not errors, (mismatch, errors)
    assert not (clean / "nuisances.json").exists() and not (clean / "tissue_mask.png").exists()
    assert "nuisance" not in json.loads((clean / "params.json").read_text())["params"]


def test_inactive_options_change_no_pixel(frames):
    """Sizes set but every share 0 and no border or overlay: frames pass unchanged."""
    options = NuisanceParams(motion_blur_px=20.0, defocus_px=5.0, washed_out_strength=1.0, repeat_quality=10)
    assert not options.active() and NuisanceParams(defocus_share=0.1).active()
    out = _run(frames, **vars(options))
    for f, (rgb, depth) in zip(out, frames):
        assert f.names == () and (f.rgb == rgb).all() and (f.depth == depth).all()


# ---------------------------------------------------------------------- seeding


@pytest.mark.parametrize("options", [
    {"border": "octagon"},
    {"overlay": True},
    {"motion_blur_share": 0.5},
    {"defocus_share": 0.5},
    {"washed_out_share": 0.5},
    {"repeat_share": 0.5},
], ids=lambda o: next(iter(o)))
def test_each_option_is_seeded(frames, options):
    frames = frames + frames  # 16 frames: two seeds choosing the same frames is unlikely (2^-16 at share 0.5)
    a, b, c = (_run(frames, seed=s, **options) for s in (SEED, SEED, SEED + 1))
    assert all(x.rgb.tobytes() == y.rgb.tobytes() and x.names == y.names for x, y in zip(a, b))
    assert any(x.rgb.tobytes() != z.rgb.tobytes() for x, z in zip(a, c))


# ---------------------------------------------------------------------- border


def _clipped_circle_area(r: float, half_w: float, half_h: float) -> float:
    """Area of a centred circle of radius r inside a centred half_w x half_h rectangle (r below
    the half-diagonal: the clipped segments do not overlap)."""
    area = math.pi * r * r
    for h in (half_w, half_w, half_h, half_h):
        if r > h:
            area -= r * r * math.acos(h / r) - h * math.sqrt(r * r - h * h)
    return area


@pytest.mark.parametrize("w,h", [(96, 72), (80, 80)])
def test_border_masks_match_their_shapes(w, h):
    side, wh = min(w, h), w * h
    cases = {
        ("circle", 0.9): math.pi * (0.45 * side) ** 2 / wh,
        ("circle", 1.1): _clipped_circle_area(0.55 * side, w / 2, h / 2) / wh,
        ("octagon", 0.9): 2 * (math.sqrt(2) - 1) * (0.9 * side) ** 2 / wh,
        ("cut_corners", 0.2): 1 - 2 * (0.2 * side) ** 2 / wh,
        ("letterbox", 0.25): 0.75,
        ("none", 1.0): 1.0,
    }
    for (shape, size), expected in cases.items():
        kw = {"corner": size} if shape == "cut_corners" else {"bars": size} if shape == "letterbox" else {"scale": size}
        mask = tissue_mask(w, h, shape, **kw)
        assert mask.shape == (h, w) and mask.dtype == bool
        assert abs(mask.mean() - expected) < 0.03 * expected, (shape, size, mask.mean(), expected)
        assert (mask == mask[::-1]).all() and (mask == mask[:, ::-1]).all(), shape  # centred
    octagon = tissue_mask(w, h, "octagon", scale=0.9)
    assert not octagon[h // 2 - int(0.44 * side), w // 2 - int(0.44 * side)]  # its diagonal edge cuts the corner
    assert octagon[h // 2, w // 2 - int(0.44 * side)] and octagon[h // 2 - int(0.44 * side), w // 2]


def test_border_is_dark_and_has_no_depth_and_depth_inside_is_unchanged(noisy, clean):
    seq, ref = Sequence(noisy), Sequence(clean)
    mask = cv2.imread(str(noisy / "tissue_mask.png"), cv2.IMREAD_UNCHANGED)
    assert mask.dtype == np.uint8 and mask.shape == (SIZE, SIZE) and set(np.unique(mask)) == {0, 255}
    inside = mask == 255
    assert (inside == tissue_mask(SIZE, SIZE, "circle", scale=1.05)).all()
    labels = read_nuisances(noisy)
    assert sorted(labels) == list(range(FRAMES)) and all("border" in v for v in labels.values())
    for name in ("motion_blur", "defocus", "washed_out", "repeat"):  # this seed gives each at least once
        assert any(name in v for v in labels.values()), (name, labels)
    for i in range(FRAMES):
        src = i
        while "repeat" in labels[src]:
            src -= 1  # a repeat shows the frame it repeats
        rgb, depth = seq.read_rgb(i), seq.read_depth(i)
        if src == i:
            assert rgb[~inside].max() < 20, i
        else:  # a JPEG copy: compression carries the tissue's light into the 8x8 blocks on the edge
            assert rgb[~inside].mean() < 12 and np.percentile(rgb[~inside], 95) < 20, i
        assert (depth[~inside] == 0).all(), i
        assert (depth[inside] == ref.read_depth(src)[inside]).all(), i
        assert np.allclose(seq.poses[i], ref.poses[src]), i


def test_overlay_is_the_only_bright_thing_in_the_border(frames):
    chain = NuisanceChain(NuisanceParams(border="octagon", overlay=True), SIZE, SIZE, 30.0, SEED)
    outside = ~chain.mask
    for i, (rgb, depth) in enumerate(frames):
        f = chain.apply(i, rgb, depth)
        text, shadow = chain.overlay(i)
        assert f.rgb[outside & (text == 0) & (shadow == 0)].max() < 20
        burned = outside & (text == 255)
        assert burned.any() and (f.rgb[burned] == OVERLAY_GREY).all()


# ---------------------------------------------------------------------- overlay


def test_clock_changes_with_the_second_and_holds_within_it(frames):
    """At 4 fps frames 0-3 show one second, 4-7 the next: the clock's fully covered pixels are
    the same within a second and change with it; label and icon never change."""
    assert clock_text(3661) == "01:01:01" and clock_text(86400 + 59) == "00:00:59"
    chain = NuisanceChain(NuisanceParams(overlay=True), SIZE, SIZE, 4.0, SEED)
    out = [chain.apply(i, rgb, depth) for i, (rgb, depth) in enumerate(frames)]
    assert [chain.clock(i) == chain.clock(0) for i in range(8)] == [True] * 4 + [False] * 4
    bottom = slice(SIZE // 2, SIZE)  # the clock sits at the bottom left, the label and icon at the top
    covers = [chain.overlay(i)[0] == 255 for i in range(FRAMES)]
    for i, f in enumerate(out):
        full = covers[i]
        assert (f.rgb[full] == OVERLAY_GREY).all()  # burned in: the scene does not show through
        assert (covers[i][: SIZE // 2] == covers[0][: SIZE // 2]).all()  # label and icon do not move
    for i in (1, 2, 3):
        assert (covers[i] == covers[0]).all()
        assert (out[i].rgb[covers[0]] == out[0].rgb[covers[0]]).all()
    assert (covers[4][bottom] != covers[3][bottom]).any()
    assert (out[4].rgb[bottom] != out[3].rgb[bottom]).any()


# ---------------------------------------------------------------------- blur, exposure, repeats


@pytest.mark.parametrize("options", [{"motion_blur_share": 1.0}, {"defocus_share": 1.0}], ids=["motion", "defocus"])
def test_blurred_frames_are_less_sharp(frames, options):
    for f, (rgb, depth) in zip(_run(frames, **options), frames):
        assert f.names == (next(iter(options)).removesuffix("_share"),)
        assert _sharpness(f.rgb) < 0.6 * _sharpness(rgb)
        assert (f.depth == depth).all()


def test_washed_out_frames_saturate_most_tissue(frames):
    for f, (rgb, _) in zip(_run(frames, washed_out_share=1.0), frames):
        luma = cv2.cvtColor(f.rgb, cv2.COLOR_RGB2GRAY)
        assert (luma >= 245).mean() > 0.5 > (cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY) >= 245).mean()


def test_repeated_frames_are_jpeg_copies_of_their_predecessor(frames):
    out = _run(frames, repeat_share=0.5, border="cut_corners")
    reps = [i for i, f in enumerate(out) if "repeat" in f.names]
    assert reps and 0 not in reps
    luma = [cv2.cvtColor(f.rgb, cv2.COLOR_RGB2GRAY).astype(float) for f in out]
    for i in reps:
        assert out[i].rgb.tobytes() != out[i - 1].rgb.tobytes()  # re-encoded, not the same bytes
        err = np.abs(luma[i] - luma[i - 1]).mean()  # JPEG error at quality 85 (64 px frames: ~3 luma)
        others = [np.abs(luma[j] - luma[i - 1]).mean() for j in range(len(out)) if out[j].source != out[i].source]
        assert err < 4.0 and err < 0.5 * min(others), (err, others)
        assert out[i].source == out[i - 1].source and (out[i].depth == out[i - 1].depth).all()
    for i, f in enumerate(out):
        if i not in reps:
            assert f.source == i


# ---------------------------------------------------------------------- settings


def test_options_are_validated_with_one_line_naming_them(tmp_path, capsys):
    for key, value in [("border", "hexagon"), ("motion_blur_share", 1.5), ("border_scale", 3.0),
                       ("repeat_quality", 0), ("overlay_text", "\u00e9cho")]:
        with pytest.raises(InputError, match=f"^nuisance.{key}:"):
            set_path(SimParams(), f"nuisance.{key}", value)
        with pytest.raises(InputError, match=f"^nuisance.{key}:"):
            NuisanceParams(**{key: value})
    p = tree_from_mapping(SimParams(), {"nuisance": {"border": "Cut-Corners", "overlay": "true"}})
    assert (p.nuisance.border, p.nuisance.overlay) == ("cut_corners", True) and p.nuisance.active()
    assert SimParams.from_dict(p.to_dict()) == p
    assert cli_main(["generate", "--out", str(tmp_path / "x"), "--set", "nuisance.border=round"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: --set: nuisance.border:") and "\n" not in err and not (tmp_path / "x").exists()


def test_contact_sheet_shows_a_sequence_with_nuisances(noisy, tmp_path):
    out = tmp_path / "sheet.png"
    argv = ["contact-sheet", str(noisy), "--out", str(out), "--count", "8", "--cols", "4", "--tile", str(SIZE)]
    assert cli_main(argv) == 0
    img = cv2.imread(str(out))
    assert img.shape == (2 * 2 * SIZE, 4 * SIZE, 3)
