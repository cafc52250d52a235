"""The zoo models on held-out simulator sequences: depth, matches, SLAM, the unseen wall,
test-time training. Writes ``benchmarks/results/zoo.md`` and ``zoo.json``.

Sections (setting ``only``; each one's numbers are kept in ``WORK/SECTION.json`` and reused unless
``--redo``):

- ``depth``: the depth entry's ONNX file on the held-out sequences (:data:`HELD_OUT`: seq1, seq3,
  seq5 x 2 seeds, 300 frames at the paper's pace, 128 px; seq5's appearance is in no training
  sequence): the seven metrics (median-scaled), the metric scale error without ground-truth
  scaling, the SimCol3D challenge's metrics.
- ``matches``: the descriptors entry's weights: recall / precision of SIFT, SIFT+kpf,
  ContraFeat, ContraFeat+kpf on frame pairs at gaps 2, 4, 8.
- ``slam``: ``c3f_slam run`` at default settings on every held-out sequence with zoo depth and
  zoo ContraFeat, and with zoo depth and SIFT; ``evaluate --gt``: frames in the main map, ATE
  after a Sim(3) alignment (cm and % of the path) and the alignment's scale.
- ``coverage``: the seven cases of ``benchmarks.protocols.coverage_accuracy`` on zoo depth (SIFT): the
  run's unseen-wall estimate against the truth.
- the setting ``slam_set`` (``--set slam_set=KEY=VALUE``, several comma-separated) is given as
  ``--set KEY=VALUE`` to every SLAM run of ``slam`` and ``coverage`` (a variant of the defaults;
  recorded with the numbers, and a section kept in WORK with other settings is computed again).
- ``ttt``: test-time training from the zoo weights (the paper's objective,
  ``configs/depthnet/ttt.yaml``, no ground truth) on two held-out sequences of a trained
  appearance and two of the unseen appearance: Abs Rel before and after.
- ``ablation``: the paper's first claim at this scale: from the zoo weights, the same number of
  self-supervised steps on four of the zoo's training sequences with the paper's objective and
  with the Monodepth2 baseline (no supervised term, no augmentation in either), for each seed;
  the held-out Sq Rel of each (mean over the seeds).
- ``ablation_selfsup``: the same from a self-supervised start instead (``start_steps`` steps of the
  Monodepth2 objective from random weights), the counterpart of the paper's ImageNet start: the
  zoo weights were trained with a supervised term, so any self-supervised step leads away from them.
- ``real``: real frames: every ``phantom_every``-th frame of the C3VD phantom clip (``--phantom DIR``:
  the clip's folder with ``split.py``, or its split; never in the repository; without it the
  section is skipped with a line saying so): for every depth entry of the zoo, Spearman's rank
  correlation of its depth (as the runtime predicts it: border filled from the tissue mask found
  from the frames) with the data set's depth render (brighter = farther) over the tissue pixels
  that are not occluded and have a rendered depth (:mod:`c3f_models.zoo.real`, the code of
  ``python -m c3f_models zoo real``; :mod:`datamodules.phantom`); the heuristic "darker is
  farther" (blurred luma) on the same pixels; the same after ``phantom_ttt_steps`` steps of
  test-time training from the entry's weights on the clip (the demo's path: the frames ingested
  as a sequence, repeats dropped; :func:`c3f_models.zoo.ttt.tune_and_export`), with the guard's
  decision; the share of the border where the network outputs depth and where the runtime passes
  it on.

    python -m benchmarks.protocols.zoo
    python -m benchmarks.protocols.zoo --set only=slam,coverage --set slam_set=match_filter.reprojection_refit=true
    python -m benchmarks.protocols.zoo --set only=real --phantom ../shared/data/c3vd_phantom_preview

Inputs: the models by name from the zoo (settings ``depth``, ``features``; trained by ``python -m
c3f_models.zoo``, not here); the held-out and training sequences generated from the recipes'
presets and seeds; sequences and runs under ``--work`` (default ``runs/bench/zoo``). Settings
(``--print-config``: each with its default and meaning): :class:`Settings`; ``--heldout`` (a
folder), ``--phantom`` (a folder) and ``--redo`` stay plain options.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from benchmarks.common import RESULTS, ROOT, WORK
from benchmarks.common.protocol_cli import REPORT_HELP, ProtocolCli, check_choices, check_not_empty
from benchmarks.common.report import Report, json_beside
from c3f_core.errors import InputError
from c3f_models.zoo.card import rho_text
from c3f_models.zoo.recipes import HELD_OUT, QUICK_HELD_OUT, TRAIN, shortened
from c3f_models.zoo.train import REPO, simulate
from c3f_models.zoo.ttt import tune_and_export

SECTIONS = ("depth", "matches", "slam", "coverage", "ttt", "ablation", "ablation_selfsup", "real")
ABLATION = {"c3fusion": "configs/depthnet/paper_objective.yaml", "monodepth2": "configs/depthnet/monodepth2.yaml"}
#: test-time training's sequences -> their appearance (seq1: trained; seq5: in no training sequence)
TTT_SEQUENCES = {"seq1_s2001": "trained", "seq1_s2002": "trained", "seq5_s2005": "unseen", "seq5_s2006": "unseen"}


#: keys of a section's result that are not per-sequence or per-case rows
META_KEYS = ("wall_s", "settings")


def _cached(work: Path, name: str, redo: bool, compute, settings: list[str] | None = None) -> dict:
    """The section's result from ``WORK/NAME.json`` if there (computed with the same SLAM
    ``settings``, where given) and not ``redo``, else computed and kept there."""
    path = work / f"{name}.json"
    if path.is_file() and not redo:
        kept = json.loads(path.read_text())
        if settings is None or kept.get("settings", []) == settings:
            return kept
    t0 = time.time()
    out = compute()
    if settings is not None:
        out["settings"] = settings
    out["wall_s"] = round(time.time() - t0, 1)
    path.write_text(json.dumps(out, indent=2) + "\n")
    return out


def _cli(args: list[str], what: str, ok: tuple[int, ...] = (0,)) -> subprocess.CompletedProcess:
    """Run ``python ARGS``; SystemExit with its last error unless its exit status is in ``ok``."""
    done = subprocess.run([sys.executable, *args], cwd=ROOT, capture_output=True, text=True)
    if done.returncode not in ok:
        raise SystemExit(f"{what} failed: {done.stderr.strip()[-300:]}")
    return done


def depth_section(a: argparse.Namespace, seqs: list[Path]) -> dict:
    from c3f_models.zoo.evaluate import depth_heldout

    return depth_heldout(a.depth, seqs)


def matches_section(a: argparse.Namespace, seqs: list[Path]) -> dict:
    import yaml

    from c3f_models.contrafeat.module import ContraFeat
    from c3f_models.zoo.evaluate import descriptor_heldout
    from c3f_slam.models import zoo
    entry = zoo.entry(a.features, "--features")
    cfg = yaml.safe_load((entry.folder / "config.yaml").read_text())["model"]["init_args"]
    model = ContraFeat(**{k: v for k, v in cfg.items() if k != "init_weights"})
    model.load_init_weights(a.features)
    model.eval()
    return descriptor_heldout(model, seqs[0].parent, [p.name for p in seqs])


def _slam_one(seq: Path, out: Path, options: list[str]) -> dict:
    run = _cli(["-m", "c3f_slam", "run", str(seq), *options, "--quiet", "--overwrite", "--out", str(out)],
               f"c3f_slam run {seq.name}", ok=(0, 2))
    if run.returncode != 0:
        return {"status": "failed", "error": run.stderr.strip().splitlines()[-1]}
    _cli(["-m", "c3f_slam", "evaluate", str(out), "--gt", str(seq)], f"evaluate {seq.name}")
    ev = json.loads((out / "evaluation.json").read_text())
    s = json.loads((out / "summary.json").read_text())
    ate = ev.get("ate_sim3") or {}
    length = ev.get("gt_length_m") or float("nan")
    fps = s.get("timings", {}).get("total", {}).get("frames_per_second")
    return {"status": "ok", "registered_share": s.get("registered_share"), "ate_cm": 100 * ate.get("rmse_m", 0.0),
            "path_cm": 100 * length, "ate_share_of_path": ate.get("rmse_m", float("nan")) / length,
            "sim3_scale": ate.get("scale"), "frames_per_s": fps}


def _set_options(settings: list[str]) -> list[str]:
    return [x for kv in settings for x in ("--set", kv)]


def slam_section(a: argparse.Namespace, seqs: list[Path]) -> dict:
    extra = _set_options(a.slam_set)
    configs = {"contrafeat": ["--depth-model", a.depth, "--feature-model", a.features, *extra],
               "sift": ["--depth-model", a.depth, "--descriptors", "sift", *extra]}
    return {name: {seq.name: _slam_one(seq, a.work / "slam" / name / seq.name, opts) for seq in seqs}
            for name, opts in configs.items()}


def coverage_section(a: argparse.Namespace) -> dict:
    from benchmarks.protocols.coverage_accuracy import CASES, run_case

    ns = argparse.Namespace(preset="seq1", seed=7, frames=300, size=128, depth_model=a.depth,
                            slam_options=_set_options(a.slam_set))
    return {c.name: run_case(c, ns, a.work / "coverage") for c in CASES}


def ttt_section(a: argparse.Namespace, seqs: list[Path]) -> dict:
    from c3f_models.zoo.evaluate import depth_heldout
    from c3f_slam.models import zoo
    entry = zoo.entry(a.depth, "--depth")
    out = {"steps": a.ttt_steps}
    for name in TTT_SEQUENCES:
        seq = next(p for p in seqs if p.name == name)
        run = a.work / "ttt" / name
        guard = tune_and_export(a.depth, entry.folder / "config.yaml", seq, run, a.ttt_steps) / "guard.json"
        before = depth_heldout(entry.file_for("depth", "--depth"), [seq])["per_sequence"][name]
        after = depth_heldout(run / "onnx" / "depthnet.onnx", [seq])["per_sequence"][name]
        out[name] = {"before": before["median_scaled"], "after": after["median_scaled"],
                     "guard": json.loads(guard.read_text()) if guard.is_file() else None}
    return out


def _ablation_settings(run: Path, seed: int, steps: int, train: list[Path],
                       init: str | None, lr: float) -> dict:
    """The last config of one ablation fit: ``steps`` steps from ``init`` (None: random), ``seed``,
    no supervised term and no augmentation, a constant learning rate, logs and checkpoint in ``run``."""
    return {"seed_everything": seed, "trainer": {
        "max_steps": steps, "max_epochs": -1, "limit_val_batches": 0, "num_sanity_val_steps": 0,
        "enable_progress_bar": False, "default_root_dir": str(run),
        "logger": {"class_path": "lightning.pytorch.loggers.TensorBoardLogger",
                   "init_args": {"save_dir": str(run), "name": "tb", "version": 0}},
        "callbacks": [{"class_path": "lightning.pytorch.callbacks.ModelCheckpoint",
                       "init_args": {"save_last": True}}]},
        "model": {"init_args": {"init_weights": init, "loss": {"lambda_gt_depth": 0.0},
                                "augment": {"p": 0.0}, "optim": {"lr": lr, "milestones": []}}},
        "data": {"init_args": {"data_dir": str(train[0].parent), "split": {
            "train": [p.name for p in train], "val": [], "test": [], "val_fraction": 0.0,
            "test_fraction": 0.0}}}}


def _ablation_train(a: argparse.Namespace) -> list[Path]:
    return simulate(shortened(TRAIN[:2], 24) if a.quick else TRAIN[:4], 128, a.work / "train")


def _ablation_pairs(a: argparse.Namespace, seqs: list[Path], train: list[Path], *, entry, init: str, folder: str,
                    init_sha256: str | None = None) -> dict:
    """Both objectives (:data:`ABLATION`) for every seed, ``a.ablation_steps`` steps from ``init``
    (its hash ``init_sha256``), under ``WORK/folder``: ``{objective: {seed: held-out mean metrics}}``."""
    out: dict = {}
    for variant, config in ABLATION.items():
        for seed in a.ablation_seeds:
            run = a.work / folder / f"{variant}_s{seed}"
            last = _ablation_settings(run, seed, a.ablation_steps, train, init, 1e-4)
            out.setdefault(variant, {})[str(seed)] = _ablation_run(run, last, [entry.folder / "config.yaml", config],
                                                                   seqs, f"{variant} seed {seed}", init_sha256)
    return out


def ablation_section(a: argparse.Namespace, seqs: list[Path]) -> dict:
    """From the zoo weights (trained with a supervised term, so near the simulator's optimum)."""
    from c3f_slam.models import zoo
    entry = zoo.entry(a.depth, "--depth")
    train = _ablation_train(a)
    return {"steps": a.ablation_steps, "seeds": list(a.ablation_seeds), "train": [p.name for p in train],
            **_ablation_pairs(a, seqs, train, entry=entry, init=a.depth, folder="ablation")}


def ablation_selfsup_section(a: argparse.Namespace, seqs: list[Path]) -> dict:
    """From a self-supervised start: the zoo entry's network trained from random weights with the
    Monodepth2 objective for ``a.start_steps`` steps (seed 0, learning rate 3e-4, the same four
    sequences), a network that predicts structure without having seen true depth; then both
    objectives as in :func:`ablation_section`. The paper starts from ImageNet weights, which
    this checkpoint stands in for (nothing is downloaded)."""
    from c3f_slam.models import zoo
    entry = zoo.entry(a.depth, "--depth")
    train = _ablation_train(a)
    run = a.work / "ablation_selfsup" / "start"
    last = _ablation_settings(run, 0, a.start_steps, train, None, 3e-4)
    start = _ablation_run(run, last, [entry.folder / "config.yaml", ABLATION["monodepth2"]], seqs, "start")
    ckpt = run / "tb" / "version_0" / "checkpoints" / "last.ckpt"
    return {"steps": a.ablation_steps, "seeds": list(a.ablation_seeds), "train": [p.name for p in train],
            "start_steps": a.start_steps, "start": start,
            **_ablation_pairs(a, seqs, train, entry=entry, init=str(ckpt), folder="ablation_selfsup",
                              init_sha256=zoo.sha256_of(ckpt))}


def _ablation_run(run: Path, last: dict, configs: list, seqs: list[Path], what: str,
                  start_sha256: str | None = None) -> dict:
    """One fit of the ablation in ``run``: fit (continued from its last checkpoint after an
    interruption), export, held-out depth metrics; a finished run with the same settings
    (``result.json``) is read back instead, so the section can run in chunks. ``start_sha256``:
    the hash of the checkpoint it starts from where that file can change under the same path
    (a run from another start is made again)."""
    import yaml

    from c3f_models.zoo.evaluate import depth_heldout

    done = run / "result.json"
    if done.is_file():
        saved = json.loads(done.read_text())
        if saved.get("settings") == last and saved.get("start_sha256") == start_sha256:
            return saved["mean"]
    ckpt = run / "tb" / "version_0" / "checkpoints" / "last.ckpt"
    same_start = (run / "start.sha256").read_text() == str(start_sha256) if (run / "start.sha256").is_file() else False
    resume = ["--ckpt_path", str(ckpt)] if ckpt.is_file() and same_start and (run / "last.yaml").is_file() and \
        yaml.safe_load((run / "last.yaml").read_text()) == last else []
    if not resume:
        shutil.rmtree(run, ignore_errors=True)
    run.mkdir(parents=True, exist_ok=True)
    (run / "last.yaml").write_text(yaml.safe_dump(last, sort_keys=False))
    (run / "start.sha256").write_text(str(start_sha256))
    _cli(["-m", "c3f_models", "fit", *(a for c in configs for a in ("--config", str(c))),
          "--config", str(run / "last.yaml"), *resume], f"ablation fit {what}")
    _cli(["-m", "c3f_models", "export", "--config", str(run / "tb" / "version_0" / "config.yaml"),
          "--ckpt_path", str(ckpt), "--output_dir", str(run / "onnx"), "--graphs", "[depth]", "--metric_scale", "1.0"],
         f"ablation export {what}")
    mean = depth_heldout(run / "onnx" / "depthnet.onnx", seqs)["mean"]
    done.write_text(json.dumps({"settings": last, "start_sha256": start_sha256, "mean": mean}, indent=1))
    return mean


def ablation_lines(t: dict, start: dict | None = None, origin: str = "From the zoo weights",
                   start_name: str = "the zoo model they start from") -> list[str]:
    """The ablation's table; ``start``: held-out metrics of the checkpoint both objectives start
    from (``start_name``), ``origin`` begins the description."""
    mean = {v: float(np.mean([r["sq_rel"] for r in t[v].values()])) for v in ABLATION if v in t}
    lines = [f"{origin}, {t['steps']} self-supervised steps on {', '.join(t['train'])} per run; seeds "
             f"{t['seeds']}; held-out Sq Rel (cm, median-scaled), mean over the held-out sequences:", "",
             "| objective | " + " | ".join(f"seed {s}" for s in t["seeds"]) + " | mean |",
             "|---|" + "---|" * (len(t["seeds"]) + 1)]
    for v, m in mean.items():
        lines.append(f"| {v} | " + " | ".join(f"{100 * t[v][str(s)]['sq_rel']:.4f}" for s in t["seeds"])
                     + f" | {100 * m:.4f} |")
    if start is not None:
        lines.append(f"| ({start_name}) | " + " | ".join("" for _ in t["seeds"])
                     + f" | {100 * start['sq_rel']:.4f} |")
    if len(mean) == 2:
        change = mean["c3fusion"] / mean["monodepth2"] - 1
        lines += ["", f"C3Fusion's Sq Rel is {abs(100 * change):.1f} % {'lower' if change < 0 else 'higher'} than "
                  "the baseline's (paper: about 15 % lower)."]
        if start is not None and min(mean.values()) > start["sq_rel"]:
            lines[-1] += (f" Both objectives end above {start_name}: at this budget, "
                          "self-supervised training from it makes the depth worse.")
    return lines


def ablation_selfsup_lines(t: dict) -> list[str]:
    return ablation_lines(t, t.get("start"), f"From a self-supervised start ({t['start_steps']} steps of the "
                          "Monodepth2 objective from random weights, seed 0, learning rate 3e-4, the same sequences; "
                          "it stands in for the paper's ImageNet start)",
                          "the self-supervised start")


def _pct(x) -> str:
    return "n/a" if x is None else f"{100 * x:.1f}"


def _depth_entries() -> list:
    """Every depth entry of the zoo (its folder), by name."""
    from c3f_slam.models import zoo

    return [e for e in zoo.entries() if e.kind == "depth"]


def real_section(a: argparse.Namespace) -> dict:
    """The ``real`` section (module notes): every depth entry of the zoo on the phantom clip
    ``a.phantom``, each scored by :func:`c3f_models.zoo.real.entry_numbers` (what ``zoo real`` records)."""
    from c3f_models.zoo import real
    from datamodules.phantom import read_phantom, split_folder

    split = split_folder(a.phantom, a.work)
    clip = read_phantom(split, a.phantom_every)
    masks = real.counted_masks(clip)
    out = {**real.clip_numbers(clip, masks), "ttt_steps": a.phantom_ttt_steps, "models": {}}
    seq = real.phantom_sequence(split, a.work / "real") if a.phantom_ttt_steps > 0 else None
    for entry in _depth_entries():
        out["models"][entry.name] = real.entry_numbers(entry, clip, masks, option="--depth",
                                                       ttt_steps=a.phantom_ttt_steps, sequence=seq,
                                                       work=a.work / "real" / "ttt" / entry.name)
    return out


def real_lines(r: dict) -> list[str]:
    frames = r["frames"]
    steps = r.get("ttt_steps", 0)
    every = frames[1] - frames[0] if len(frames) > 1 else 1
    text = (f"One frame in {every} of the C3VD phantom clip "
            f"({len(frames)} frames: {frames[0]}..{frames[-1]}; a real colonoscope in a silicone phantom, "
            "the data set's preview, never in the repository). Spearman rank correlation of predicted depth with the "
            "data set's depth render (8-bit grey, brighter = farther), over the pixels of the tissue area found from "
            f"the frames ({_pct(r['tissue_share'])} % of the frame; {r['tissue_source']}) that are not occluded and "
            f"have a rendered depth ({_pct(r['counted_share'])} % of the frame): mean over the frames (median; all "
            "pixels pooled). Depth as the runtime predicts it (the border filled from the tissue area in the network "
            "input).")
    if steps:
        text += (f" After: {steps} steps of test-time training from the entry's weights on the clip's frames "
                 "(ttt.yaml + paper_objective.yaml, batch 4, no ground truth; repeated frames dropped), the guard on.")
    lines = [text, "",
             "| depth | Spearman | after test-time training | change | border with network depth % | "
             "border with runtime depth % | guard: kept step, events |", "|---|---|---|---|---|---|---|"]
    for name, m in r["models"].items():
        b, f, g = m["before"], m.get("after"), m.get("guard") or {}
        change = (f"{f['spearman']['mean'] - b['spearman']['mean']:+.3f}"
                  if f and f["spearman"]["mean"] is not None and b["spearman"]["mean"] is not None else "")
        events = ", ".join(e["event"] for e in g.get("events", [])) or "none"
        lines.append(f"| zoo:{name} | {rho_text(b['spearman'])} | {rho_text(f['spearman']) if f else 'not measured'} | "
                     f"{change} | {_pct(b['outside_network'])} | {_pct(b['outside_runtime'])} | "
                     f"{(str(g.get('best_step', 'n/a')) + ', ' + events) if f else ''} |")
    lines.append(f"| darker is farther (blurred luma) | {rho_text(r['darker_is_farther'])} | | | | | |")
    return lines


def depth_lines(d: dict) -> list[str]:
    from c3f_models.zoo.card import _depth_table

    s = d["simcol3d"]
    return [*_depth_table({"depth": d}), "",
            f"SimCol3D protocol (least-squares scale per sequence), mean over sequences: L1 {s['l1_cm']:.3f} cm, "
            f"relative error {s['median_rel_pct']:.2f} %, RMSE {s['rmse_cm']:.3f} cm."]


def matches_lines(m: dict) -> list[str]:
    from c3f_models.zoo.card import _match_table

    return _match_table({"descriptors": m})


def _settings_lines(section: dict) -> list[str]:
    given = section.get("settings") or []
    return [f"Not the defaults: every run with `{' '.join(_set_options(given))}`.", ""] if given else []


def slam_lines(s: dict) -> list[str]:
    lines = [*_settings_lines(s),
             "| sequence | descriptors | in the main map % | ATE Sim(3) cm | path cm | ATE % of path | Sim(3) scale |",
             "|---|---|---|---|---|---|---|"]
    for name, runs in s.items():
        if name in META_KEYS:
            continue
        for seq, r in runs.items():
            if r["status"] != "ok":
                lines.append(f"| {seq} | {name} | failed: {r['error']} | | | | |")
                continue
            lines.append(f"| {seq} | {name} | {_pct(r['registered_share'])} | {r['ate_cm']:.2f} | "
                         f"{r['path_cm']:.1f} | {_pct(r['ate_share_of_path'])} | {r['sim3_scale']:.3f} |")
    return lines


def coverage_lines(c: dict) -> list[str]:
    lines = [*_settings_lines(c), "| case | registered % | truth unseen % | estimate % | error pp |",
             "|---|---|---|---|---|"]
    for name, u in c.items():
        if name in META_KEYS:
            continue
        if u.get("status") != "ok":
            lines.append(f"| {name} | {u.get('status')} | | | |")
            continue
        lines.append(f"| {name} | {_pct(u['registered_share'])} | {_pct(u['truth'])} | {_pct(u['estimate'])} | "
                     f"{u['error_pp']:+.1f} |")
    return lines


def ttt_lines(t: dict) -> list[str]:
    lines = [f"{t['steps']} steps of batch 4 of the paper's objective (configs/depthnet/ttt.yaml + "
             "paper_objective.yaml: PoseNet alone for the first 30 steps while the depth network's batch-norm "
             "statistics follow the sequence, then both networks; the guard on), from the zoo weights, no ground "
             "truth. What the other schedules do: docs/lab_notes/2026-12-04-zoo-ttt-variants.md.", "",
             "| sequence | appearance | Abs Rel before | after | change % | δ<1.25 before | after | "
             "guard: kept step, events |", "|---|---|---|---|---|---|---|---|"]
    for name, appearance in TTT_SEQUENCES.items():
        if name in t:
            b, f, g = t[name]["before"], t[name]["after"], t[name].get("guard") or {}
            events = ", ".join(e["event"] for e in g.get("events", [])) or "none"
            lines.append(f"| {name} | {appearance} | {b['abs_rel']:.4f} | {f['abs_rel']:.4f} | "
                         f"{100 * (f['abs_rel'] / b['abs_rel'] - 1):+.1f} | {b['a1']:.3f} | {f['a1']:.3f} | "
                         f"{g.get('best_step', 'n/a')}, {events} |")
    return lines


def _slam_ok(s: dict, name: str) -> list[dict]:
    return [r for r in s.get(name, {}).values() if isinstance(r, dict) and r.get("status") == "ok"]


def target_lines(m: dict) -> list[str]:
    """Each target of the zoo against what was measured (met / not met / not measured)."""
    rows = []

    def row(what: str, measured: str, met: bool | None) -> None:
        rows.append(f"| {what} | {measured} | {'met' if met else 'not met' if met is not None else 'not measured'} |")

    if "depth" in m:
        d = m["depth"]["mean"]
        row("depth Abs Rel <= 0.10 and δ<1.25 >= 0.90 (median-scaled, mean of the held-out sequences)",
            f"{d['abs_rel']:.3f}, {d['a1']:.3f}", d["abs_rel"] <= 0.10 and d["a1"] >= 0.90)
        e = m["depth"]["median_scale_error"]
        row("metric scale error <= 10 % (median per sequence, recorded scale, no GT scaling)", f"{100 * e:.1f} %",
            e <= 0.10)
    if "matches" in m:
        mm = m["matches"]["mean"]
        row("ContraFeat+kpf recall >= 75 % at precision >= 99.5 %",
            f"{100 * mm['cdf_kpf_recall']:.1f} / {100 * mm['cdf_kpf_precision']:.1f} %",
            mm["cdf_kpf_recall"] >= 0.75 and mm["cdf_kpf_precision"] >= 0.995)
    if "slam" in m:
        s, n = m["slam"], max(len(v) for k, v in m["slam"].items() if k not in META_KEYS)
        for name in ("contrafeat", "sift"):
            ok = _slam_ok(s, name)
            reg = [r["registered_share"] for r in ok]
            share = [r["ate_share_of_path"] for r in ok]
            scale = [abs(r["sim3_scale"] - 1) for r in ok]
            row(f"SLAM ({name}): >= 95 % of frames in one map, ATE <= 1 % of the path, Sim(3) scale within 10 % "
                "of 1, on every held-out sequence",
                f"{len(ok)} of {n} ran; registered min {_pct(min(reg, default=None))} %, ATE max "
                f"{_pct(max(share, default=None))} % of the path, scale off by at most {_pct(max(scale, default=None))}"
                " %", len(ok) == n and min(reg) >= 0.95 and max(share) <= 0.01 and max(scale) <= 0.10)
        cf, sift = _slam_ok(s, "contrafeat"), _slam_ok(s, "sift")
        if cf and sift:
            a, b = np.mean([r["ate_cm"] for r in cf]), np.mean([r["ate_cm"] for r in sift])
            row("ContraFeat's ATE no worse than SIFT's (same predicted depth; mean over sequences)",
                f"{a:.3f} vs {b:.3f} cm", len(cf) == len(sift) and a <= b)
    if "coverage" in m:
        cases = [u for k, u in m["coverage"].items() if k not in META_KEYS]
        ok = [u for u in cases if u.get("status") == "ok"]
        errs = [abs(u["error_pp"]) for u in ok]
        row("unseen-wall estimate within 5 points of the truth on the 7 coverage cases",
            f"{len(ok)} of {len(cases)} ran; |error| max {max(errs, default=float('nan')):.1f} pp",
            len(ok) == len(cases) and max(errs) <= 5)
    for name, origin in (("ablation", "from the zoo weights"), ("ablation_selfsup", "from a self-supervised start")):
        if name in m and all(v in m[name] for v in ABLATION):
            t = m[name]
            c, b = (float(np.mean([r["sq_rel"] for r in t[v].values()])) for v in ABLATION)
            row(f"the paper's objective: Sq Rel >= 15 % lower than the Monodepth2 baseline (same start and budget; "
                f"{origin}, mean of {len(t['seeds'])} seeds)",
                f"{100 * c:.3f} vs {100 * b:.3f} cm ({100 * (c / b - 1):+.1f} %)", c <= 0.85 * b)
    if "ttt" in m:
        t = m["ttt"]
        change = {a: [t[n]["after"]["abs_rel"] / t[n]["before"]["abs_rel"] - 1 for n, k in TTT_SEQUENCES.items()
                      if k == a and n in t] for a in ("unseen", "trained")}
        if change["unseen"] and change["trained"]:
            du, dl = max(change["unseen"]), max(change["trained"])
            row("test-time training lowers Abs Rel on every sequence of the unseen appearance, raises it <= 5 % on "
                "the trained one (largest change of each)", f"{100 * du:+.1f} % / {100 * dl:+.1f} %",
                du < 0 and dl <= 0.05)
    return ["| target | measured | |", "|---|---|---|", *rows]


#: each section's Markdown from (its result, every section's result: the ablation shows the depth section's start)
RENDER = {"depth": lambda d, m: depth_lines(d), "matches": lambda d, m: matches_lines(d),
          "slam": lambda d, m: slam_lines(d), "coverage": lambda d, m: coverage_lines(d),
          "ttt": lambda d, m: ttt_lines(d),
          "ablation": lambda d, m: ablation_lines(d, m.get("depth", {}).get("mean")),
          "ablation_selfsup": lambda d, m: ablation_selfsup_lines(d), "real": lambda d, m: real_lines(d)}
TITLES = {"depth": "Depth (held-out)", "matches": "Matches (held-out pairs)", "slam": "SLAM at default settings",
          "coverage": "Unseen wall on zoo depth (coverage_accuracy cases, SIFT)", "ttt": "Test-time training",
          "ablation": "The paper's objective against the Monodepth2 baseline (same start, same budget)",
          "ablation_selfsup": "The same from a self-supervised start",
          "real": "Real frames (C3VD phantom clip, depth render)"}


@dataclass(frozen=True)
class Settings:
    """What zoo measures."""

    depth: str = "zoo:c3f-depth-r18w32"  #: depth model (zoo:NAME)
    features: str = "zoo:c3f-features-r18w32"  #: descriptor model (zoo:NAME)
    #: sections run: depth, matches, slam, coverage, ttt, ablation, ablation_selfsup, real (real: with --phantom)
    only: tuple[str, ...] = SECTIONS
    #: settings KEY=VALUE of every SLAM run of the slam and coverage sections (c3f_slam run --set KEY=VALUE)
    slam_set: tuple[str, ...] = ()
    ttt_steps: int = 60  #: test-time training steps, as the demo (ZOO_TTT_STEPS)
    ablation_steps: int = 300  #: self-supervised steps of each ablation fit
    ablation_seeds: tuple[int, ...] = (1, 2, 3)  #: seeds of the ablation fits
    #: ablation_selfsup: steps of the Monodepth2 objective from random weights that make the start
    start_steps: int = 400
    phantom_every: int = 24  #: real: take every N-th frame of the phantom clip (frames)
    #: real: test-time training steps (batch 4) on the phantom clip from each depth entry; 0: none
    phantom_ttt_steps: int = 60
    #: a check of the script: 16-frame held-out sequences, tiny training data (numbers mean nothing)
    quick: bool = False

    def __post_init__(self) -> None:
        check_not_empty(self, "only", "ablation_seeds")
        if self.phantom_every < 1:
            raise InputError(f"phantom_every must be at least 1, got {self.phantom_every}")
        if self.phantom_ttt_steps < 0:
            raise InputError(f"phantom_ttt_steps must be 0 or more, got {self.phantom_ttt_steps}")
        check_choices("only", self.only, SECTIONS)


CLI = ProtocolCli("zoo", Settings, __doc__, example="only=depth,slam")


def main(argv: list[str] | None = None) -> None:
    ap = CLI.parser()
    ap.add_argument("--work", type=Path, default=WORK / "zoo", help="folder for sequences, runs and section results")
    ap.add_argument("--redo", action="store_true", help="recompute sections whose JSON is in --work")
    ap.add_argument("--report", type=Path, default=RESULTS / "zoo.md", help=REPORT_HELP)
    ap.add_argument("--heldout", type=Path, default=REPO / "runs" / "zoo" / "heldout",
                    help="folder of the held-out sequences (made when missing; the recipes' evaluation uses the same)")
    ap.add_argument("--phantom", type=Path,
                    help="section real: the phantom clip's folder (with split.py) or its split (rgb/, depth_render/, "
                         "occlusion/, camera.json); without it the section is skipped")
    options, settings = CLI.parse(ap, argv)
    a = CLI.flat(options, settings)  # the sections read their settings from one namespace (a.depth, a.work, ...)
    wanted = [name for name in SECTIONS if name in a.only]
    if "real" in wanted and a.phantom is None:
        wanted.remove("real")
        if not wanted:
            ap.error("--phantom: section real needs the phantom clip's folder (--phantom DIR)")
        print("zoo: section real skipped: no --phantom DIR given", file=sys.stderr)
    a.work.mkdir(parents=True, exist_ok=True)
    heldout = QUICK_HELD_OUT if a.quick else HELD_OUT
    made: list[Path] = []

    def seqs() -> list[Path]:  # the held-out sequences, simulated only for a section that reads them
        if not made:
            made.extend(simulate(heldout, 128, a.work / "heldout" if a.quick else a.heldout))
        return made

    compute = {"depth": lambda: depth_section(a, seqs()), "matches": lambda: matches_section(a, seqs()),
               "slam": lambda: slam_section(a, seqs()), "coverage": lambda: coverage_section(a),
               "ttt": lambda: ttt_section(a, seqs()), "ablation": lambda: ablation_section(a, seqs()),
               "ablation_selfsup": lambda: ablation_selfsup_section(a, seqs()), "real": lambda: real_section(a)}
    keys = {"slam": a.slam_set, "coverage": a.slam_set}
    if "real" in wanted:  # kept in WORK with the clip, the frames, the steps and the depth entries' files
        keys["real"] = [f"phantom={a.phantom.resolve()}", f"phantom_every={a.phantom_every}",
                        f"phantom_ttt_steps={a.phantom_ttt_steps}", *(
                            f"zoo:{e.name}={f.sha256[:12]}" for e in _depth_entries()
                            for f in e.files.values() if f.role == "depth")]
    results = {name: _cached(a.work, name, a.redo, compute[name], keys.get(name)) for name in wanted}
    json_path = json_beside(a.report)
    old = json.loads(json_path.read_text()) if json_path.is_file() else {}
    merged = {**old.get("data", old).get("sections", {}), **results}  # (a file of before Report.publish: no "data")
    body = [f"Models: `{a.depth}`, `{a.features}`. Held-out sequences: " + ", ".join(s.name for s in heldout)
            + f" ({heldout[0].frames} frames at {heldout[0].step_mm:.2f} mm per frame, 128 px; seq5's appearance is in "
            "no training sequence). "
            f"Numbers also in `{json_path.name}`.", "", "## Targets", "", *target_lines(merged), ""]
    for name in SECTIONS:
        if name in merged:
            title = "SLAM" if name == "slam" and merged[name].get("settings") else TITLES[name]
            body += [f"## {title}", "", *RENDER[name](merged[name], merged),
                     "", f"({merged[name].get('wall_s', 'n/a')} s)", ""]
    rep = Report(__file__, "The zoo models on held-out simulator sequences", argv)
    rep.publish(a.report, body, settings, options=options,
                data={"depth_model": settings.depth, "features_model": settings.features,
                      "heldout": [s.name for s in heldout], "sections": merged})
    print(f"wrote {a.report} and {json_path}")


if __name__ == "__main__":
    main()
