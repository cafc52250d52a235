"""The model card of a zoo entry (``zoo/NAME/README.md``), Hugging Face's convention: YAML front
matter (licence, data, ``model-index`` metrics) and then the text. The project's own
machine-readable part sits under ``c3fusion`` (kind, files with their SHA-256, training, the
held-out numbers); :mod:`c3f_slam.models.zoo` reads it back. Every number comes from the recipe run's
``recipe.json`` and ``evaluation.json``; nothing is typed in by hand.
"""

from __future__ import annotations

import math
from pathlib import Path

import yaml

from c3f_models.zoo.recipes import DATASETS, Recipe, SimSpec

LICENSE = "apache-2.0"
DEPTH_METRICS = {"abs_rel": "Abs Rel", "sq_rel": "Sq Rel (cm)", "rmse": "RMSE (cm)", "rmse_log": "RMSE log",
                 "a1": "δ<1.25", "a2": "δ<1.25²", "a3": "δ<1.25³"}
IN_CM = {"sq_rel", "rmse"}
MATCH_METHODS = {"sift": "SIFT", "sift_kpf": "SIFT+kpf", "cdf": "ContraFeat", "cdf_kpf": "ContraFeat+kpf"}
SIMCOL3D = {"l1_cm": "L1 (cm)", "median_rel_pct": "relative error (%)", "rmse_cm": "RMSE (cm)"}
#: the numbers a one-line summary of an entry shows (zoo list, the zoo's index, the demo report)
SUMMARY_NUMBERS = {"abs_rel": "Abs Rel", "a1": "δ<1.25", "abs_rel_unseen_appearance": "Abs Rel, unseen appearance",
                   "median_scale_error": "metric scale error", "cdf_kpf_recall": "ContraFeat+kpf recall",
                   "cdf_kpf_precision": "precision", "sift_kpf_recall": "SIFT+kpf recall",
                   "sift_kpf_precision": "precision"}
TRAINED_APPEARANCES = ("seq1", "seq2", "seq3", "seq4")


def headline(recipe: Recipe, results: dict) -> dict[str, float]:
    """The card's main numbers (flat, fractions and metres as computed)."""
    if recipe.kind == "depth":
        d = results["depth"]
        out = {f"{k}": d["mean"][k] for k in DEPTH_METRICS}
        out["median_scale_error"] = d["median_scale_error"]
        out.update({f"simcol3d_{k}": v for k, v in d["simcol3d"].items() if k in SIMCOL3D})
        unseen = [v for k, v in d["per_sequence"].items() if not k.startswith(TRAINED_APPEARANCES)]
        if unseen:
            out["abs_rel_unseen_appearance"] = sum(v["median_scaled"]["abs_rel"] for v in unseen) / len(unseen)
        return out
    m = results["descriptors"]["mean"]
    return {f"{k}_{q}": m[f"{k}_{q}"] for k in MATCH_METHODS for q in ("recall", "precision")}


def _model_index(recipe: Recipe, nums: dict[str, float], heldout: tuple[SimSpec, ...]) -> list[dict]:
    data = {"type": "c3fusion-colon-simulator", "split": "test",
            "name": f"held-out simulator sequences ({', '.join(s.name for s in heldout)}; 128 px)"}
    if recipe.kind == "depth":
        task = {"type": "depth-estimation", "name": "Monocular depth (per-image median scaling)"}
        metrics = [{"type": k, "name": DEPTH_METRICS[k], "value": round(nums[k] * (100 if k in IN_CM else 1), 4)}
                   for k in DEPTH_METRICS]
        metrics.append({"type": "scale_error", "name": "median per-sequence metric scale error (no GT scaling)",
                        "value": round(nums["median_scale_error"], 4)})
    else:
        task = {"type": "image-feature-extraction", "name": "Keypoint matching (SIFT keypoints, kpf filter)"}
        metrics = [{"type": f"{k}_{q}", "name": f"{MATCH_METHODS[k]} {q}", "value": round(nums[f'{k}_{q}'], 4)}
                   for k in MATCH_METHODS for q in ("recall", "precision")]
    return [{"name": recipe.name, "results": [{"task": task, "dataset": data, "metrics": metrics}]}]


def front_matter(recipe: Recipe, state: dict, step: int, files: dict, results: dict,
                 heldout: tuple[SimSpec, ...]) -> dict:
    nums = headline(recipe, results)
    wall = sum(c["wall_s"] for c in state.get("chunks", []))
    machines = sorted({c["machine"] for c in state.get("chunks", [])})
    return {
        "license": LICENSE,
        "library_name": "c3fusion",
        "pipeline_tag": "depth-estimation" if recipe.kind == "depth" else "image-feature-extraction",
        "tags": ["colonoscopy", "endoscopy", "onnx", "c3fusion",
                 "monocular-depth" if recipe.kind == "depth" else "local-descriptors"],
        "datasets": ["c3fusion-colon-simulator", *([recipe.dataset] if recipe.dataset else [])],
        "model-index": _model_index(recipe, nums, heldout),
        "c3fusion": {
            "kind": recipe.kind,
            "summary": recipe.summary,
            "recipe": recipe.name,
            "files": files,
            "training": {"steps": step, "wall_s": round(wall, 1), "machine": machines,
                         "command": recipe.command,
                         "config": recipe.config, "chunks": len(state.get("chunks", [])),
                         **({"init": f"zoo:{recipe.init}"} if recipe.init else {})},
            "heldout": [s.name for s in heldout],
            "metrics": {k: round(v, 5) for k, v in nums.items() if not math.isnan(v)},
        },
    }


def _depth_table(results: dict) -> list[str]:
    d = results["depth"]
    lines = ["| sequence | frames | " + " | ".join(DEPTH_METRICS.values()) + " | scale ratio (metric) |",
             "|---|---|" + "---|" * (len(DEPTH_METRICS) + 1)]
    for name, r in d["per_sequence"].items():
        cells = [f"{r['median_scaled'][k] * (100 if k in IN_CM else 1):.4f}" for k in DEPTH_METRICS]
        lines.append(f"| {name} | {r['frames']} | " + " | ".join(cells) + f" | {r['scale_ratio']:.3f} |")
    cells = [f"**{d['mean'][k] * (100 if k in IN_CM else 1):.4f}**" for k in DEPTH_METRICS]
    lines.append("| **mean** | | " + " | ".join(cells) + f" | median error **{d['median_scale_error']:.3f}** |")
    return lines


def _match_table(results: dict) -> list[str]:
    d = results["descriptors"]
    lines = ["| sequence | " + " | ".join(f"{v} recall / precision [%]" for v in MATCH_METHODS.values()) + " |",
             "|---|" + "---|" * len(MATCH_METHODS)]
    rows = [(name, {k.removeprefix("test/"): v for k, v in r.items()}) for name, r in d["per_sequence"].items()]
    for name, r in [*rows, ("**mean**", d["mean"])]:
        cells = [f"{100 * r[f'{k}_recall']:.1f} / {100 * r[f'{k}_precision']:.1f}" for k in MATCH_METHODS]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return lines


def _storage_lines(recipe: Recipe, results: dict) -> list[str]:
    """What the float16 storage of the shipped files costs: the same numbers from the float32 checkpoint."""
    if recipe.kind == "depth" and "depth_float32" in results:
        a, b = results["depth_float32"]["mean"], results["depth"]["mean"]
        return ["Float16 storage (the shipped files) against the float32 checkpoint, same frames: Abs Rel "
                f"{b['abs_rel']:.5f} vs {a['abs_rel']:.5f}, δ<1.25 {b['a1']:.5f} vs {a['a1']:.5f}.", ""]
    if recipe.kind == "descriptors" and "descriptors_float32" in results:
        a, b = results["descriptors_float32"]["mean"], results["descriptors"]["mean"]
        return ["Float16 weights (shipped) against the float32 checkpoint, same pairs: ContraFeat+kpf recall / "
                f"precision {100 * b['cdf_kpf_recall']:.2f} / {100 * b['cdf_kpf_precision']:.2f} % vs "
                f"{100 * a['cdf_kpf_recall']:.2f} / {100 * a['cdf_kpf_precision']:.2f} %.", ""]
    return []


def _tuning_lines(recipe: Recipe) -> list[str]:
    if recipe.kind == "depth":
        cfg = f"--config zoo/{recipe.name}/config.yaml"
        return [f"python -m c3f_models fit {cfg} --config configs/depthnet/ttt.yaml \\",
                "    --config configs/depthnet/paper_objective.yaml \\",
                f"    --model.init_weights zoo:{recipe.name} --data.data_dir SEQ   # test-time training on a sequence"]
    return [f"python -m c3f_models fit --config configs/trainer/gpu.yaml --config zoo/{recipe.name}/config.yaml \\",
            f"    --model.init_weights zoo:{recipe.name} --data.data_dir DATA  # fine-tuning"]


def _data_line(recipe: Recipe) -> str:
    """The card's line on the training data: the simulator's sequences, or the published data set's folder."""
    if recipe.dataset:
        module, title = DATASETS[recipe.dataset]
        return (f"- Data: {title} as published or converted, the folder given with `--data` (`{module}`, its "
                "automatic split).")
    looks = " with randomised looks (`_l<seed>`: `datamodules.synthetic.randomize.sample_look`)" if any(
        s.look is not None for s in recipe.train) else ""
    return ("- Data (simulator, `python -m datamodules.synthetic generate`, 128 px" + looks + "): training "
            + ", ".join(f"{s.name} ({s.frames} frames, {s.step_mm:.2f} mm/frame)" for s in recipe.train)
            + "; validation " + ", ".join(s.name for s in recipe.val) + ".")


def body(recipe: Recipe, state: dict, step: int, files: dict, results: dict, heldout: tuple[SimSpec, ...]) -> str:
    chunks = state.get("chunks", [])
    wall = sum(c["wall_s"] for c in chunks)
    flag = "--depth-model" if recipe.kind == "depth" else "--feature-model"
    lines = [
        f"# {recipe.name}", "", recipe.summary + ".", "",
        "## Use", "",
        "```bash",
        f"python -m c3f_slam run SEQ {flag} zoo:{recipe.name} --out OUT      # the runtime (ONNX, no torch)",
        *_tuning_lines(recipe),
        "```", "",
        "## Training", "",
        f"- Command: `{recipe.command}` (config `{recipe.config}`); {step} optimiser "
        f"steps in {len(chunks)} chunk(s), {wall / 60:.1f} min of wall time on "
        + "; ".join(sorted({c['machine'] for c in chunks})) + ".",
        *([f"- Start: the weights of `zoo:{recipe.init}` (fine-tuned)."] if recipe.init else []),
        _data_line(recipe),
        "", "## Held-out results", "",
        "Sequences never used for training: " + ", ".join(f"{s.name}" for s in heldout)
        + f" ({heldout[0].frames} frames each, {heldout[0].step_mm:.2f} mm/frame, 128 px). "
        + ("seq5 is in no training sequence (the randomised looks may come near its orange, dark, grainy mucosa)."
           if any(s.look is not None for s in recipe.train) else
           "seq5's appearance (orange, dark, grainy mucosa) is in no training sequence."), "",
        *(_depth_table(results) if recipe.kind == "depth" else _match_table(results)), "",
    ]
    if recipe.kind == "depth":
        lines += ["Median-scaled metrics per image (Monodepth2's protocol); Sq Rel and RMSE in cm. The scale ratio "
                  "is median(true) / median(predicted x the recorded metric scale): 1 means metric depth with no "
                  f"ground-truth scaling (recorded scale: {results['depth']['metric_scale_in_model']}).", "",
                  "SimCol3D challenge protocol (one least-squares scale per sequence, as its evaluation code; "
                  "`c3f_slam.io.simcol3d`), mean over the sequences: "
                  + ", ".join(f"{name} {results['depth']['simcol3d'][k]:.3f}" for k, name in SIMCOL3D.items())
                  + ".", ""]
    lines += [*_storage_lines(recipe, results), "## Deviations from the paper", "",
              *(f"- {d}" for d in recipe.deviations), "",
              "## Known limits", "", *(f"- {x}" for x in recipe.limits), "",
              "## Files", "", "| file | role | bytes | SHA-256 |", "|---|---|---|---|",
              *(f"| `{n}` | {f['role']} | {f['bytes']:,} | `{f['sha256']}` |" for n, f in files.items()), "",
              "`config.yaml` holds the model options the weights fit; `evaluation.json` every number above.", ""]
    return "\n".join(lines)


def write_card(path: Path, recipe: Recipe, *, state: dict, step: int, files: dict, results: dict,
               heldout: tuple[SimSpec, ...]) -> Path:
    meta = front_matter(recipe, state, step, files, results, heldout)
    text = "---\n" + yaml.safe_dump(meta, sort_keys=False, allow_unicode=True) + "---\n" + body(
        recipe, state, step, files, results, heldout)
    path.write_text(text, encoding="utf-8")
    return path




def summary_numbers(metrics: dict) -> str:
    """The :data:`SUMMARY_NUMBERS` of a card's metrics, one line."""
    return ", ".join(f"{label} {metrics[k]:.3f}" for k, label in SUMMARY_NUMBERS.items() if k in metrics)


def write_index(root: Path) -> Path:
    """``ROOT/README.md``: the zoo's table of entries (name, kind, summary, headline numbers),
    made from the cards (:mod:`c3f_slam.models.zoo`) each time an entry is packaged."""
    from c3f_slam.models import zoo
    lines = ["# The C3Fusion model zoo", "",
             "Trained models the project ships, each made by one command (`python -m c3f_models zoo train NAME`) "
             "and described by its model card (`NAME/README.md`: data, training, held-out numbers, deviations "
             "from the paper, limits, SHA-256 of every file). Load them by name wherever a model path is taken:",
             "", "```bash",
             "python -m c3f_models zoo list                                   # what is here",
             "python -m c3f_slam run SEQ --depth-model zoo:NAME --feature-model zoo:NAME --out OUT",
             "python -m c3f_models fit ... --model.init_weights zoo:NAME        # fine-tuning, test-time training",
             "```", "", "A file whose SHA-256 differs from its card is refused. This table is generated from the "
             "cards by `zoo train`.", "", "| entry | kind | what | held-out numbers (see its card) |",
             "|---|---|---|---|"]
    for e in zoo.entries(root):
        lines.append(f"| [{e.name}]({e.name}/README.md) | {e.kind} | {e.summary} | {summary_numbers(e.metrics)} |")
    path = root / "README.md"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


__all__ = ["SUMMARY_NUMBERS", "front_matter", "headline", "summary_numbers", "write_card", "write_index"]
