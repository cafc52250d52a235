"""The model card of a zoo entry (``zoo/NAME/README.md``), Hugging Face's convention: YAML front
matter (licence, data, ``model-index`` metrics) and then the text. The project's own
machine-readable part sits under ``c3fusion`` (kind, files with their SHA-256, training, the
held-out numbers, the real-frame numbers when measured); :mod:`c3f_slam.models.zoo` reads it back.
Every number comes from the recipe run's ``recipe.json`` and ``evaluation.json`` (its ``real`` part
from ``zoo real``: :mod:`c3f_models.zoo.real`); nothing is typed in by hand. A card is re-rendered
from the installed entry alone (:func:`rewrite_card`).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import yaml

from c3f_core.atomic import atomic_write
from c3f_core.errors import InputError
from c3f_models.zoo.recipes import DATASETS, HELD_OUT, QUICK_HELD_OUT, RECIPES, Recipe, SimSpec, quick

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
#: the real frames' data set in the card's model-index
REAL_DATASET = {"type": "c3vd-phantom-preview", "name": "C3VD phantom preview (real frames)"}
#: what the real-frame numbers do not say (the card lists them beside the numbers)
REAL_LIMITS = (
    "A silicone phantom filmed with a real colonoscope, scored against a depth rendered from the phantom's "
    "registered model, is not a patient: one scene, no mucus, bubbles, blood, peristalsis or variation between "
    "patients.",
    "The reference is an 8-bit relative depth render (brighter = farther, no unit): only the rank correlation is "
    "meaningful, not Abs Rel, δ or the metric scale.",
    "The camera is guessed (C3VD's 1350x1080 camera scaled to the 446x448 panel, as a pinhole), not calibrated.",
)


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


def _model_index(recipe: Recipe, nums: dict[str, float], heldout: tuple[SimSpec, ...],
                 more: list[dict]) -> list[dict]:
    """The model-index: the held-out results, then ``more`` (the real frames' result, when measured)."""
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
    return [{"name": recipe.name, "results": [{"task": task, "dataset": data, "metrics": metrics}, *more]}]


def training_record(recipe: Recipe, state: dict, step: int) -> dict:
    """The card's ``c3fusion.training`` from a recipe run's ``recipe.json`` (``state``) and its
    optimiser ``step``: steps, wall time (s, summed over the fit's chunks), machines, command, config."""
    chunks = state.get("chunks", [])
    return {"steps": step, "wall_s": round(sum(c["wall_s"] for c in chunks), 1),
            "machine": sorted({c["machine"] for c in chunks}), "command": recipe.command,
            "config": recipe.config, "chunks": len(chunks), **({"init": f"zoo:{recipe.init}"} if recipe.init else {})}


def rho_text(r: dict | None) -> str:
    """A :func:`~c3f_slam.evaluation.rank_depth.rank_depth` result as ``mean (median; pooled)``, or n/a."""
    if not r or r.get("mean") is None:
        return "n/a"
    pooled = "n/a" if r.get("pooled") is None else f"{r['pooled']:.3f}"
    return f"{r['mean']:.3f} ({r['median']:.3f}; {pooled})"


def real_command(name: str, *, every: int | None = None, ttt_steps: int | None = None) -> str:
    """The ``zoo real`` command line that measures entry ``name`` on the phantom clip (``DIR``)."""
    return (f"python -m c3f_models zoo real {name} --phantom DIR" + (f" --every {every}" if every else "")
            + (f" --ttt-steps {ttt_steps}" if ttt_steps is not None else ""))


def real_numbers(results: dict) -> dict | None:
    """The card's ``c3fusion.real``: the real-frame Spearman (mean over the frames) before and, when
    measured, after test-time training, the darker-is-farther baseline, the frames; None when
    ``results`` (evaluation.json) has no ``real`` part."""
    r = results.get("real")
    if not r:
        return None

    def mean(x: dict | None) -> float | None:
        return None if not x or x.get("mean") is None else round(x["mean"], 4)

    out = {"clip": r["clip"], "frames": len(r["frames"]), "every": r["every"], "date": r["date"],
           "spearman": mean(r["before"]["spearman"]), "ttt_steps": r["ttt_steps"]}
    if "after" in r:
        out["spearman_after_ttt"] = mean(r["after"]["spearman"])
    out["darker_is_farther"] = mean(r["darker_is_farther"])
    return out


def _real_index(results: dict) -> list[dict]:
    """The model-index result of the real frames (none when not measured)."""
    nums = real_numbers(results)
    if nums is None:
        return []
    r = results["real"]
    metrics = [{"type": "spearman", "name": "Spearman rank correlation with the depth render (mean over frames)",
                "value": nums["spearman"]}]
    if "spearman_after_ttt" in nums:
        metrics.append({"type": "spearman", "name": f"the same after {nums['ttt_steps']} steps of test-time training",
                        "value": nums["spearman_after_ttt"]})
    return [{"task": {"type": "depth-estimation", "name": "Monocular depth (rank correlation with a relative "
                      "reference)"},
             "dataset": {**REAL_DATASET, "split": f"every {r['every']} frames ({nums['frames']} frames)"},
             "metrics": metrics}]


def front_matter(recipe: Recipe, training: dict, files: dict, results: dict, heldout: tuple[SimSpec, ...]) -> dict:
    """The card's YAML front matter (``training``: :func:`training_record`)."""
    nums = headline(recipe, results)
    real = real_numbers(results)
    return {
        "license": LICENSE,
        "library_name": "c3fusion",
        "pipeline_tag": "depth-estimation" if recipe.kind == "depth" else "image-feature-extraction",
        "tags": ["colonoscopy", "endoscopy", "onnx", "c3fusion",
                 "monocular-depth" if recipe.kind == "depth" else "local-descriptors"],
        "datasets": ["c3fusion-colon-simulator", *([recipe.dataset] if recipe.dataset else [])],
        "model-index": _model_index(recipe, nums, heldout, _real_index(results)),
        "c3fusion": {
            "kind": recipe.kind,
            "summary": recipe.summary,
            "recipe": recipe.name,
            "files": files,
            "training": training,
            "heldout": [s.name for s in heldout],
            "metrics": {k: round(v, 5) for k, v in nums.items() if not math.isnan(v)},
            **({"real": real} if real else {}),
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


def _real_lines(name: str, results: dict) -> list[str]:
    """The card's "Real frames" section of a depth entry: the numbers of ``zoo real`` with their
    frames, command and limits, or that they were not measured and the command that measures them."""
    r = results.get("real")
    head = ["## Real frames", ""]
    if not r:
        return [*head, f"Not measured on real frames. `{real_command(name)}` measures it (DIR: the C3VD phantom "
                "preview clip's folder with its split.py, or its split) and adds the numbers here.", ""]
    frames, steps = r["frames"], r["ttt_steps"]
    rows = [f"| zoo:{name} | {rho_text(r['before']['spearman'])} |"]
    if "after" in r:
        g = r.get("guard") or {}
        events = ", ".join(e["event"] for e in g.get("events", [])) or "none"
        rows.append(f"| zoo:{name} after {steps} steps of test-time training (guard: kept step "
                    f"{g.get('best_step', 'n/a')}; {events}) | {rho_text(r['after']['spearman'])} |")
    rows.append(f"| darker is farther (blurred luma), the same pixels | {rho_text(r['darker_is_farther'])} |")
    return [*head,
            f"One frame in {r['every']} of the C3VD phantom preview clip (`{r['clip']}`: {len(frames)} frames, "
            f"{frames[0]}..{frames[-1]}; a real colonoscope in a silicone phantom). {r['convention']}.", "",
            "| depth | Spearman: mean (median; pooled) |", "|---|---|", *rows, "",
            f"Measured on {r['date']} by `{real_command(name, every=r['every'], ttt_steps=steps)}` (DIR: the "
            f"clip's folder or its split; here `{r['clip']}`)"
            + ("." if steps else "; no test-time training."), "",
            "Limits:", "", *(f"- {x}" for x in REAL_LIMITS), ""]


def body(recipe: Recipe, training: dict, files: dict, results: dict, heldout: tuple[SimSpec, ...]) -> str:
    """The card's Markdown after the front matter (``training``: :func:`training_record`)."""
    flag = "--depth-model" if recipe.kind == "depth" else "--feature-model"
    lines = [
        f"# {recipe.name}", "", recipe.summary + ".", "",
        "## Use", "",
        "```bash",
        f"python -m c3f_slam run SEQ {flag} zoo:{recipe.name} --out OUT      # the runtime (ONNX, no torch)",
        *_tuning_lines(recipe),
        "```", "",
        "## Training", "",
        f"- Command: `{recipe.command}` (config `{recipe.config}`); {training['steps']} optimiser "
        f"steps in {training['chunks']} chunk(s), {training['wall_s'] / 60:.1f} min of wall time on "
        + "; ".join(training["machine"]) + ".",
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
    lines += _storage_lines(recipe, results)
    if recipe.kind == "depth":
        lines += _real_lines(recipe.name, results)
    lines += ["## Deviations from the paper", "",
              *(f"- {d}" for d in recipe.deviations), "",
              "## Known limits", "", *(f"- {x}" for x in recipe.limits), "",
              "## Files", "", "| file | role | bytes | SHA-256 |", "|---|---|---|---|",
              *(f"| `{n}` | {f['role']} | {f['bytes']:,} | `{f['sha256']}` |" for n, f in files.items()), "",
              "`config.yaml` holds the model options the weights fit; `evaluation.json` every number above.", ""]
    return "\n".join(lines)


def write_card(path: Path, recipe: Recipe, *, training: dict, files: dict, results: dict,
               heldout: tuple[SimSpec, ...]) -> Path:
    """Write the card ``path`` (front matter and text) of an entry of ``recipe``."""
    meta = front_matter(recipe, training, files, results, heldout)
    text = "---\n" + yaml.safe_dump(meta, sort_keys=False, allow_unicode=True) + "---\n" + body(
        recipe, training, files, results, heldout)
    with atomic_write(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return path


def card_recipe(own: dict, where: str) -> Recipe:
    """The recipe a card's ``c3fusion`` part names (a quick check's: the quick version); InputError
    naming the card ``where`` when it names none that exists."""
    name = str(own.get("recipe"))
    base = name.removesuffix("-quick")
    if base not in RECIPES:
        raise InputError(f"{where}: c3fusion.recipe {name!r} is no recipe of this checkout (there are: "
                         f"{', '.join(RECIPES)}); the card cannot be made again")
    return quick(RECIPES[base]) if name.endswith("-quick") else RECIPES[base]


def card_inputs(folder: Path) -> tuple[Recipe, dict, dict, tuple[SimSpec, ...]]:
    """What the card of the installed entry ``folder`` is made from, read from its own front
    matter: (recipe, training, files with their SHA-256, held-out sequences); InputError naming the
    card when it cannot be made again (no such recipe or held-out sequence in this checkout)."""
    from c3f_slam.models.zoo import CARD, read_entry

    own, where = read_entry(folder).own, str(folder / CARD)
    recipe = card_recipe(own, where)
    pool = {s.name: s for s in (QUICK_HELD_OUT if recipe.quick else HELD_OUT)}
    missing = [n for n in own.get("heldout", []) if n not in pool]
    if missing or not own.get("heldout"):
        raise InputError(f"{where}: held-out sequence(s) {', '.join(missing) or '(none listed)'} unknown to the "
                         "recipes; the card cannot be made again")
    return recipe, own["training"], own["files"], tuple(pool[n] for n in own["heldout"])


def rewrite_card(folder: Path) -> Path:
    """Render the card of the installed entry ``folder`` again from :func:`card_inputs` and its
    ``evaluation.json``: what ``zoo real`` runs after adding the real-frame numbers; every other
    number stays as it was."""
    from c3f_slam.models.zoo import CARD

    recipe, training, files, heldout = card_inputs(folder)
    results = json.loads((folder / "evaluation.json").read_text())
    return write_card(folder / CARD, recipe, training=training, files=files, results=results, heldout=heldout)


def summary_numbers(metrics: dict) -> str:
    """The :data:`SUMMARY_NUMBERS` of a card's metrics, one line."""
    return ", ".join(f"{label} {metrics[k]:.3f}" for k, label in SUMMARY_NUMBERS.items() if k in metrics)


def real_summary(own: dict) -> str:
    """A card's real-frame numbers (its ``c3fusion`` part) in one line: empty for a descriptors
    entry, "not measured" for a depth entry without them."""
    if own.get("kind") != "depth":
        return ""
    r = own.get("real")
    if not r:
        return "not measured"

    def num(x: float | None) -> str:
        return "n/a" if x is None else f"{x:.3f}"

    after = (f", {num(r['spearman_after_ttt'])} after {r['ttt_steps']} test-time training steps"
             if "spearman_after_ttt" in r else "")
    return f"Spearman {num(r['spearman'])}{after} (darker is farther {num(r['darker_is_farther'])})"


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
             "cards by `zoo train` and `zoo real` (real frames: the C3VD phantom clip, Spearman rank correlation "
             "with its depth render; see each card).", "",
             "| entry | kind | what | held-out numbers (see its card) | real frames |", "|---|---|---|---|---|"]
    for e in zoo.entries(root):
        lines.append(f"| [{e.name}]({e.name}/README.md) | {e.kind} | {e.summary} | {summary_numbers(e.metrics)} "
                     f"| {real_summary(e.own)} |")
    path = root / "README.md"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


__all__ = ["REAL_LIMITS", "SUMMARY_NUMBERS", "card_inputs", "card_recipe", "front_matter", "headline", "real_command",
           "real_numbers", "real_summary", "rewrite_card", "rho_text", "summary_numbers", "training_record",
           "write_card", "write_index"]
