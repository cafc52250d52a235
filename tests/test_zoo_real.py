"""``python -m c3f_models zoo real``: a zoo depth entry scored on real frames (a tiny fake phantom
split in split.py's layout, made here), the numbers stored in evaluation.json and shown on the
card and the index, the files' SHA-256 still valid; refusals in one line; the zoo protocol's
``real`` section built by the same code. No phantom clip, no training."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from c3f_models.zoo import real
from c3f_models.zoo.card import REAL_DATASET, rewrite_card, rho_text, training_record, write_card
from c3f_models.zoo.cli import main
from c3f_models.zoo.recipes import QUICK_HELD_OUT, RECIPES, quick
from c3f_slam.models import zoo
from datamodules.phantom import read_phantom
from tests import onnx_fixtures as fx

RECIPE = quick(RECIPES["c3f-depth-r18w32"])
NAME = RECIPE.name


def _phantom_split(folder: Path, n: int = 6, size: tuple[int, int] = (64, 60)) -> Path:
    """A split clip as split.py writes it (rgb/, depth_render/, occlusion/ as 3-channel NNNNNN.png,
    camera.json): a round view on a black border whose brightness grows with the rendered depth
    (brighter = farther in both), the top rows occluded."""
    w, h = size
    yy, xx = np.mgrid[:h, :w]
    r = np.hypot(xx - w / 2, yy - h / 2)
    inside = r < 0.45 * min(w, h)
    rng = np.random.default_rng(1)
    for d in ("rgb", "depth_render", "occlusion"):
        (folder / d).mkdir(parents=True)
    for k in range(n):
        grey = np.clip(60 + 6 * r + 8 * k, 1, 255) * inside
        rgb = np.clip(grey[..., None] + rng.uniform(-3, 3, (h, w, 3)), 0, 255) * inside[..., None]
        occ = np.zeros((h, w), np.uint8)
        occ[:6] = 255
        cv2.imwrite(str(folder / "rgb" / f"{k:06d}.png"), rgb.astype(np.uint8))
        cv2.imwrite(str(folder / "depth_render" / f"{k:06d}.png"), cv2.merge([grey.astype(np.uint8)] * 3))
        cv2.imwrite(str(folder / "occlusion" / f"{k:06d}.png"), cv2.merge([occ] * 3))
    cam = {"width": w, "height": h, "fx": 50.0, "fy": 50.0, "cx": (w - 1) / 2, "cy": (h - 1) / 2,
           "distortion": [], "depth_scale": 10000.0}
    (folder / "camera.json").write_text(json.dumps(cam, indent=2))
    return folder


def _results() -> dict:
    """A depth entry's evaluation.json (made-up held-out numbers, the layout package.py writes)."""
    metrics = {"abs_rel": 0.1, "sq_rel": 0.001, "rmse": 0.005, "rmse_log": 0.12, "a1": 0.9, "a2": 0.99, "a3": 0.999}
    seq = {"frames": 5, "median_scaled": metrics, "scale_ratio": 1.02}
    return {"depth": {"mean": metrics, "median_scale_error": 0.02, "metric_scale_in_model": 1.0,
                      "simcol3d": {"l1_cm": 0.3, "median_rel_pct": 8.0, "rmse_cm": 0.5},
                      "per_sequence": {s.name: seq for s in QUICK_HELD_OUT}}, "evaluation_wall_s": 1.0}


@pytest.fixture
def real_zoo(tmp_path, monkeypatch) -> Path:
    """A zoo with a depth entry packaged as package.py does (the closed-form ONNX depth: brighter =
    farther; its card by write_card) and a descriptors entry."""
    root = tmp_path / "zoo"
    entry = root / NAME
    entry.mkdir(parents=True)
    fx.depth_model(entry / "depthnet.onnx", size=(32, 32), dynamic=True)
    files = {"depthnet.onnx": {"role": "depth", "sha256": zoo.sha256_of(entry / "depthnet.onnx"),
                               "bytes": (entry / "depthnet.onnx").stat().st_size}}
    (entry / "evaluation.json").write_text(json.dumps(_results(), indent=2) + "\n")
    training = training_record(RECIPE, {"chunks": [{"wall_s": 12.3, "machine": "test machine"}]}, RECIPE.steps)
    write_card(entry / zoo.CARD, RECIPE, training=training, files=files, results=_results(), heldout=QUICK_HELD_OUT)
    desc = root / "tiny-features"
    desc.mkdir()
    fx.descriptor_model(desc / "contrafeat.onnx", dim=8, dynamic=True)
    meta = {"c3fusion": {"kind": "descriptors", "summary": "a descriptors test entry", "files": {"contrafeat.onnx": {
        "role": "descriptors", "sha256": zoo.sha256_of(desc / "contrafeat.onnx"),
        "bytes": (desc / "contrafeat.onnx").stat().st_size}}}}
    (desc / zoo.CARD).write_text("---\n" + yaml.safe_dump(meta) + "---\n# test entry\n")
    monkeypatch.setenv(zoo.ENV, str(root))
    return root


def _card(root: Path) -> tuple[dict, str]:
    return zoo.split_card((root / NAME / zoo.CARD).read_text(encoding="utf-8"), "card")


def test_a_card_without_real_numbers_says_not_measured(real_zoo):
    meta, body = _card(real_zoo)
    assert "## Real frames" in body and "Not measured on real frames" in body
    assert f"`python -m c3f_models zoo real {NAME} --phantom DIR`" in body
    assert "real" not in meta["c3fusion"] and len(meta["model-index"][0]["results"]) == 1
    assert "Real frames" not in (real_zoo / "tiny-features" / zoo.CARD).read_text()


def test_zoo_real_records_the_spearman_on_the_card(real_zoo, tmp_path, capsys):
    split = _phantom_split(tmp_path / "clip")
    meta_before, body_before = _card(real_zoo)
    assert main(["real", NAME, "--phantom", str(split), "--every", "2", "--work", str(tmp_path / "work")]) == 0
    assert "Spearman" in capsys.readouterr().out
    results = json.loads((real_zoo / NAME / "evaluation.json").read_text())
    r = results["real"]
    assert results["depth"] == _results()["depth"]  # the other numbers stay
    assert r["frames"] == [0, 2, 4] and r["every"] == 2 and r["clip"] == "clip" and r["ttt_steps"] == 0
    assert r["convention"] == real.CONVENTION and len(r["date"]) == 10 and "after" not in r
    rho, luma = r["before"]["spearman"]["mean"], r["darker_is_farther"]["mean"]
    assert rho > 0.5 and luma < -0.5  # the model orders as the render does (at its 32 px); "darker is farther" not

    meta, body = _card(real_zoo)
    assert "Not measured" not in body and f"| zoo:{NAME} | {rho_text(r['before']['spearman'])} |" in body
    assert f"| darker is farther (blurred luma), the same pixels | {rho_text(r['darker_is_farther'])} |" in body
    assert "3 frames, 0..4" in body and f"zoo real {NAME} --phantom DIR --every 2 --ttt-steps 0" in body
    assert "is not a patient" in body and "only the rank correlation is meaningful" in body and "guessed" in body
    extra = meta["model-index"][0]["results"][1]
    assert extra["dataset"]["name"] == REAL_DATASET["name"]
    assert extra["metrics"][0] == {"type": "spearman", "name": extra["metrics"][0]["name"], "value": round(rho, 4)}
    assert meta["c3fusion"]["real"]["spearman"] == round(rho, 4)
    own = {k: v for k, v in meta["c3fusion"].items() if k != "real"}
    assert own == meta_before["c3fusion"] and meta["model-index"][0]["results"][0] == \
        meta_before["model-index"][0]["results"][0]
    assert body.split("## Real frames")[0] == body_before.split("## Real frames")[0]

    index = (real_zoo / "README.md").read_text()
    assert f"Spearman {rho:.3f} (darker is farther {luma:.3f})" in index
    text = (real_zoo / NAME / zoo.CARD).read_text(encoding="utf-8")
    rewrite_card(real_zoo / NAME)
    assert (real_zoo / NAME / zoo.CARD).read_text(encoding="utf-8") == text  # deterministic
    assert main(["verify"]) == 0
    assert main(["list"]) == 0 and f"real frames: Spearman {rho:.3f}" in capsys.readouterr().out


@pytest.mark.parametrize("args, words", [
    (["real", "tiny-features", "--phantom", "CLIP"], ("zoo real", "tiny-features is a descriptors model")),
    (["real", NAME, "--phantom", "NOWHERE"], ("--phantom", "no such folder")),
    (["real", NAME, "--phantom", "EMPTY"], ("--phantom", "neither a split clip")),
    (["real", NAME, "--phantom", "CLIP", "--every", "0"], ("--every", "at least 1")),
    (["real", NAME, "--phantom", "CLIP", "--ttt-steps", "-1"], ("--ttt-steps", "0 or more")),
])
def test_zoo_real_refuses_in_one_line(real_zoo, tmp_path, capsys, args, words):
    places = {"CLIP": _phantom_split(tmp_path / "clip"), "NOWHERE": tmp_path / "nowhere", "EMPTY": tmp_path}
    card = (real_zoo / NAME / zoo.CARD).read_text(encoding="utf-8")
    rc = main([str(places.get(a, a)) for a in args] + ["--work", str(tmp_path / "w")])
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert rc == 2 and len(err) == 1 and err[0].startswith("error: ") and all(w in err[0] for w in words)
    assert (real_zoo / NAME / zoo.CARD).read_text(encoding="utf-8") == card
    assert "real" not in json.loads((real_zoo / NAME / "evaluation.json").read_text())


def test_the_protocols_real_section_is_built_by_the_shared_code(real_zoo, tmp_path, monkeypatch):
    from benchmarks.protocols import zoo as protocol

    split = _phantom_split(tmp_path / "clip")
    calls = []
    shared = real.entry_numbers

    def spy(entry, *args, **kwargs):
        calls.append((entry.name, kwargs.get("option")))
        return shared(entry, *args, **kwargs)

    monkeypatch.setattr(real, "entry_numbers", spy)
    a = argparse.Namespace(phantom=split, work=tmp_path / "work", phantom_every=2, phantom_ttt_steps=0)
    out = protocol.real_section(a)
    assert calls == [(NAME, "--depth")]  # every depth entry, the descriptors one left out
    clip = read_phantom(split, 2)
    masks = real.counted_masks(clip)
    assert {k: out[k] for k in real.clip_numbers(clip, masks)} == real.clip_numbers(clip, masks)
    assert out["models"][NAME] == shared(zoo.entry(NAME), clip, masks)
    assert main(["real", NAME, "--phantom", str(split), "--every", "2", "--work", str(tmp_path / "w")]) == 0
    stored = json.loads((real_zoo / NAME / "evaluation.json").read_text())["real"]
    assert stored["before"] == out["models"][NAME]["before"]  # the command and the protocol agree
    assert stored["darker_is_farther"] == out["darker_is_farther"]
    assert "| zoo:" + NAME in "\n".join(protocol.real_lines(out))


def test_the_clip_for_test_time_training_is_ingested_as_the_demo_does(tmp_path):
    split = _phantom_split(tmp_path / "clip", n=5)
    seq = real.phantom_sequence(split, tmp_path / "work")
    record = json.loads((seq / "ingest.json").read_text())
    assert record["settings"] == {"max_fps": 60.0, "max_frames": 10000, "max_side": 256}
    assert record["frames"] == len(list((seq / "rgb").glob("*.png"))) >= 3 and (seq / "camera.json").is_file()
    assert real.phantom_sequence(split, tmp_path / "work") == seq  # made once
