"""A zoo depth model on real frames: the C3VD phantom clip (:mod:`datamodules.phantom`) scored
against the data set's depth render. What ``python -m c3f_models zoo real NAME --phantom DIR``
records in the entry's ``evaluation.json`` (``real``) and card, and what the zoo protocol's
``real`` section runs for every depth entry (``benchmarks.protocols.zoo``).

Convention (:data:`CONVENTION`): Spearman's rank correlation
(:mod:`c3f_slam.evaluation.rank_depth`) of the depth as the runtime predicts it
(:class:`~c3f_slam.pipeline.frontend.ModelDepth`: the border filled from the tissue area found
from the frames, depth outside it 0) with the render (8-bit grey, brighter = farther, relative),
over the tissue pixels that are not occluded and have a rendered depth; per frame, then mean,
median and all pixels pooled. The baseline on the same pixels: "darker is farther" (blurred
luma). Optionally the same after test-time training from the entry's weights on the clip
(:func:`c3f_models.zoo.ttt.tune_and_export`: the paper's objective, batch 4, the guard on) on
the clip's frames ingested as the demo ingests a video (:func:`datamodules.ingest.ingest`: repeats
dropped, 256 px).
"""

from __future__ import annotations

import json
import shutil
import time
from datetime import UTC, datetime
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from c3f_core.atomic import atomic_write
from c3f_core.errors import InputError
from c3f_models.zoo.card import rewrite_card, write_index
from c3f_models.zoo.ttt import tune_and_export
from datamodules.ingest import ingest
from datamodules.phantom import PhantomFrames, frame_names, read_phantom, split_folder, write_video

#: the default frame step on the clip (frames): 13 of its 289 frames, about 0.4 s apart
EVERY = 24
#: how the Spearman is computed (recorded with the numbers, shown on the card)
CONVENTION = ("Spearman rank correlation of the depth as the runtime predicts it (the border filled from the "
              "tissue area found from the frames) with the data set's depth render (8-bit grey, brighter = farther, "
              "relative), over the tissue pixels that are not occluded and have a rendered depth: mean over the "
              "frames (median; all pixels pooled)")


def counted_masks(clip: PhantomFrames) -> list[np.ndarray]:
    """Per frame of ``clip``, the (H, W) bool pixels that count (:meth:`PhantomFrames.valid`)."""
    return [clip.valid(k) for k in range(len(clip.indices))]


def clip_numbers(clip: PhantomFrames, masks: list[np.ndarray]) -> dict:
    """What does not depend on the model: the frames used, the tissue area (share 0..1 of the
    frame, and how it was found), the share of the frame counted, the darker-is-farther baseline."""
    from c3f_slam.evaluation.rank_depth import luminance_depth, rank_depth

    return {"frames": clip.indices, "tissue_share": clip.tissue.share, "tissue_source": clip.tissue.source,
            "counted_share": float(np.mean([m.mean() for m in masks])),
            "darker_is_farther": rank_depth([luminance_depth(f) for f in clip.rgb], clip.depth, masks)}


def model_on_clip(model_path: Path, clip: PhantomFrames, masks: list[np.ndarray]) -> dict:
    """One depth model (ONNX) on the frames of ``clip`` as the runtime predicts: Spearman with the
    render inside ``masks``; the share (0..1, mean over frames) of the border where the network
    outputs depth and where the runtime passes depth on."""
    from c3f_slam.evaluation.rank_depth import outside_share, rank_depth
    from c3f_slam.models.nets import DepthModel
    from c3f_slam.pipeline.frontend import ModelDepth

    model = DepthModel(model_path, threads=2)
    runtime = ModelDepth(model, clip.camera, tissue=clip.tissue.pixels)
    preds, net_out, run_out = [], [], []
    for k, rgb in enumerate(clip.rgb):
        net, view = model.predict_network(rgb, clip.camera, clip.tissue.pixels)
        net_out.append(outside_share(view.network_to_frame(net, model.upsample), clip.tissue.pixels))
        depth = runtime.predict(SimpleNamespace(rgb=rgb, index=k)).frame
        run_out.append(outside_share(depth, clip.tissue.pixels))
        preds.append(depth)
    return {"spearman": rank_depth(preds, clip.depth, masks),
            "outside_network": float(np.mean(net_out)) if None not in net_out else None,
            "outside_runtime": float(np.mean(run_out)) if None not in run_out else None}


def phantom_sequence(split: Path, work: Path, *, max_side: int = 256) -> Path:
    """The split clip's frames as a sequence folder ``work/phantom_seq`` (made once), for
    test-time training: the frames as a 60 frames/s video, then the demo's ingest
    (:func:`datamodules.ingest.ingest`: every frame, repeats dropped, at most ``max_side`` pixels on
    the long side, times.txt and the tissue mask beside)."""
    seq = work / "phantom_seq"
    if (seq / "camera.json").is_file():
        return seq
    video = write_video([split / "rgb" / n for n in frame_names(split)], work / "phantom_seq_video" / "phantom.mp4")
    (video.parent / "camera.json").write_text((split / "camera.json").read_text())
    ingest(video, seq, max_fps=60.0, max_frames=10000, max_side=max_side)
    return seq


def entry_numbers(entry, clip: PhantomFrames, masks: list[np.ndarray], *, option: str = "zoo real",
                  ttt_steps: int = 0, sequence: Path | None = None, work: Path | None = None) -> dict:
    """Zoo depth ``entry`` (:class:`c3f_slam.models.zoo.ZooEntry`) on ``clip``: ``before``
    (:func:`model_on_clip` of its ONNX file); with ``ttt_steps`` > 0, test-time training from its
    weights on ``sequence`` (:func:`phantom_sequence`) in ``work`` (emptied first), then ``after``
    (the same numbers), ``guard`` (the guard's record) and ``ttt_wall_s``. InputError naming
    ``option`` when the entry is not a depth model or a file differs from its card."""
    row = {"before": model_on_clip(entry.file_for("depth", option), clip, masks)}
    if ttt_steps > 0:
        if sequence is None or work is None:
            raise ValueError("test-time training needs the clip's sequence and a work folder")
        weights = entry.file_for("weights", option, kind="depth")
        shutil.rmtree(work, ignore_errors=True)
        t0 = time.time()
        guard = tune_and_export(str(weights), entry.folder / "config.yaml", sequence, work, ttt_steps) / "guard.json"
        row.update(after=model_on_clip(work / "onnx" / "depthnet.onnx", clip, masks),
                   guard=json.loads(guard.read_text()) if guard.is_file() else None,
                   ttt_wall_s=round(time.time() - t0, 1))
    return row


def measure(entry, phantom: Path, work: Path, *, every: int = EVERY, ttt_steps: int = 0) -> dict:
    """The ``real`` record of zoo depth ``entry`` on the phantom clip ``phantom`` (its folder with
    split.py, split into ``work``, or its split): every ``every``-th frame, ``ttt_steps`` steps of
    test-time training (0: none); the clip's name, the frames, the convention and the date (UTC)
    beside the numbers. InputError naming the option on bad input."""
    if every < 1:
        raise InputError(f"--every must be at least 1, got {every}")
    if ttt_steps < 0:
        raise InputError(f"--ttt-steps must be 0 or more, got {ttt_steps}")
    split = split_folder(phantom, work)
    clip = read_phantom(split, every)
    masks = counted_masks(clip)
    sequence = phantom_sequence(split, work) if ttt_steps > 0 else None
    row = entry_numbers(entry, clip, masks, ttt_steps=ttt_steps, sequence=sequence, work=work / "ttt" / entry.name)
    return {"clip": Path(phantom).resolve().name, "every": every, "convention": CONVENTION,
            "date": datetime.now(UTC).date().isoformat(), "ttt_steps": ttt_steps,
            **clip_numbers(clip, masks), **row}


def record(entry, real: dict) -> Path:
    """Store ``real`` (:func:`measure`) under ``real`` in the entry's ``evaluation.json`` (the other
    numbers unchanged), then render its card and the zoo's index again. ``evaluation.json`` is not
    among the files the card hashes, so every SHA-256 stays valid. Returns the card."""
    path = entry.folder / "evaluation.json"
    if not path.is_file():
        raise InputError(f"zoo real: zoo:{entry.name}: {path} is missing (the card's numbers come from it)")
    results = {**json.loads(path.read_text()), "real": real}
    with atomic_write(path) as tmp:
        tmp.write_text(json.dumps(results, indent=2) + "\n")
    card = rewrite_card(entry.folder)
    write_index(entry.folder.parent)
    return card


__all__ = ["CONVENTION", "EVERY", "clip_numbers", "counted_masks", "entry_numbers", "measure", "model_on_clip",
           "phantom_sequence", "record"]
