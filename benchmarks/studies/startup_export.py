"""Start-up of the project's commands and the phases of an ONNX export: what costs the time, what is avoidable.

Three parts (``--parts``, default all):

- ``startup``: each command of :data:`COMMANDS` (``--help`` of every entry point, ``zoo list``,
  the demo's own process, ``c3f_slam run --print-config``) with the code of ``--before`` and of
  ``--after``, alternating, ``--repeats`` times each: wall time of the whole process (medians and
  their ratio), and which of torch, Lightning, Open3D, OpenCV, onnxruntime it imported
  (``python -X importtime``, one run per side). Each process runs in its tree (``PYTHONPATH``
  set to it, the tree as working directory).
- ``export``: ``python -m c3f_models export`` of the zoo's two models (their config and float16
  weights, the data module on a simulated folder under ``--work``) with both trees, alternating,
  ``--export-repeats`` times each; and, with the code of ``--after``, where the time of one such
  process goes: importing torch and Lightning, per graph ``torch.onnx.export`` (its own steps:
  the op registry, capture by ``torch.export``, decomposition, translation, the onnxscript
  optimiser), the parity check, the metric-scale calibration, writing the files.
- ``variants``: per graph, in one process, alternating: the exporter as used
  (``dynamo=True``, optimised, dynamic height and width), without the onnxscript optimiser,
  with a fixed frame size, and the TorchScript exporter (``dynamo=False``): export seconds, ONNX
  nodes, parity with PyTorch and onnxruntime latency of the four-frame batch. None of them
  writes the same file; they show what each choice costs.

    python -m benchmarks.studies.startup_export --before /tmp/before --repeats 5 --export-repeats 3

(``/tmp/before``: a checkout of the reference commit, e.g. ``git worktree add /tmp/before REV``).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import time
from pathlib import Path

from benchmarks.common import ROOT, STUDIES, WORK
from benchmarks.common.report import Report
from benchmarks.common.simulate import SimSequence, ensure_sequence

SIDES = ("before", "after")
#: (label, module and arguments after ``python -m``, the exit status it ends with); ``{bad_out}`` is
#: a file, so the demo stops with exit status 2 right after importing its stages
COMMANDS: tuple[tuple[str, tuple[str, ...], int], ...] = (
    ("c3f_models --help", ("c3f_models", "--help"), 0),
    ("c3f_models export --help", ("c3f_models", "export", "--help"), 0),
    ("c3f_models zoo list", ("c3f_models", "zoo", "list"), 0),
    ("c3f_models zoo show NAME --json", ("c3f_models", "zoo", "show", "c3f-depth-r18w32", "--json"), 0),
    ("c3f_demo --help", ("c3f_demo", "--help"), 0),
    ("c3f_demo --out FILE (its own process, stopped by bad input)", ("c3f_demo", "--out", "{bad_out}"), 2),
    ("c3f_slam --help", ("c3f_slam", "--help"), 0),
    ("c3f_slam run --help", ("c3f_slam", "run", "--help"), 0),
    ("c3f_slam run --print-config", ("c3f_slam", "run", "--print-config"), 0),
)
HEAVY = ("torch", "lightning", "open3d", "cv2", "onnxruntime")
ZOO_MODELS = ("c3f-depth-r18w32", "c3f-features-r18w32")
#: the simulated data folder of the exports: two training sequences and a held-out one (128 px, true depth)
DATA = {"train0": SimSequence("seq1", 100, 40, 128, ("path.coverage=0.1",)),
        "train1": SimSequence("seq1", 101, 40, 128, ("path.coverage=0.1",)),
        "heldout": SimSequence("seq2", 7, 30, 128, ("path.coverage=0.1",))}


def _env(tree: Path) -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(tree), "PYTHONDONTWRITEBYTECODE": "1"}


def run_timed(tree: Path, args: list[str], status: int = 0) -> float:
    """Seconds ``python ARGS`` took in ``tree``; SystemExit naming the command when it ends with
    another exit status than ``status``."""
    t = time.perf_counter()
    r = subprocess.run([sys.executable, *args], cwd=tree, env=_env(tree), capture_output=True, text=True)
    dt = time.perf_counter() - t
    if r.returncode != status:
        raise SystemExit(f"{tree}: python {' '.join(args)} ended with {r.returncode}: {r.stderr.strip()[-500:]}")
    return dt


def heavy_imports(tree: Path, args: list[str], status: int) -> list[str]:
    """Which of :data:`HEAVY` ``python -X importtime ARGS`` imported in ``tree``."""
    r = subprocess.run([sys.executable, "-X", "importtime", *args], cwd=tree, env=_env(tree), capture_output=True,
                       text=True)
    if r.returncode != status:
        raise SystemExit(f"{tree}: python {' '.join(args)} ended with {r.returncode}")
    names = {m.group(1) for m in re.finditer(r"^import time:.*\|\s+(\w+)$", r.stderr, re.M)}
    return [h for h in HEAVY if h in names]


def measure_startup(trees: dict[str, Path], repeats: int, work: Path) -> list[dict]:
    """Per command of :data:`COMMANDS`: the seconds of each run per side (alternating) and the heavy imports."""
    work.mkdir(parents=True, exist_ok=True)
    bad_out = work / "not_a_folder"
    bad_out.write_text("")
    rows = []
    for label, argv, status in COMMANDS:
        args = ["-m", *(a.replace("{bad_out}", str(bad_out)) for a in argv)]
        times: dict[str, list[float]] = {s: [] for s in SIDES}
        for _ in range(repeats):
            for side in SIDES:
                times[side].append(run_timed(trees[side], args, status))
        rows.append({"command": label, "seconds": times,
                     "imports": {s: heavy_imports(trees[s], args, status) for s in SIDES}})
        print(f"{label}: before {statistics.median(times['before']):.2f} s, after "
              f"{statistics.median(times['after']):.2f} s", flush=True)
    return rows


def export_args(model: str, data: Path, out: Path) -> list[str]:
    """The options of ``python -m c3f_models export`` of the zoo model ``model`` on ``data`` into ``out``."""
    return ["export", "--config", str(ROOT / "zoo" / model / "config.yaml"), "--ckpt_path",
            str(ROOT / "zoo" / model / "weights.safetensors"), "--data.data_dir", str(data), "--output_dir", str(out)]


def ensure_data(work: Path) -> Path:
    """The simulated data folder of :data:`DATA` under ``work`` (made once)."""
    for name, spec in DATA.items():
        ensure_sequence(spec, work / "data" / name, overwrite=True)
    return work / "data"


def measure_export_commands(trees: dict[str, Path], repeats: int, work: Path) -> dict[str, dict[str, list[float]]]:
    """Seconds of ``python -m c3f_models export`` per zoo model and side, alternating."""
    data = ensure_data(work)
    res: dict[str, dict[str, list[float]]] = {m: {s: [] for s in SIDES} for m in ZOO_MODELS}
    for _ in range(repeats):
        for model in ZOO_MODELS:
            for side in SIDES:
                res[model][side].append(run_timed(trees[side], ["-m", "c3f_models",
                                                                *export_args(model, data, work / f"out_{side}")]))
    return res


def measure_phases(tree: Path, model: str, work: Path) -> dict:
    """Where one export process of ``model`` spends its time (:mod:`benchmarks.common.export_phases`, run
    in ``tree`` as a subprocess): its JSON, plus ``process`` (the whole process's seconds)."""
    data = ensure_data(work)
    out = work / "phases.json"
    t = time.perf_counter()
    subprocess.run([sys.executable, "-m", "benchmarks.common.export_phases", "--json", str(out), "--",
                    *export_args(model, data, work / "out_phases")], cwd=tree, env=_env(tree), check=True,
                   capture_output=True)
    return {**json.loads(out.read_text()), "process": time.perf_counter() - t}


def _med(values: list[float]) -> float:
    return statistics.median(values) if values else float("nan")


def startup_lines(rows: list[dict]) -> list[str]:
    lines = ["## Start-up", "",
             "| command | before (s) | after (s) | after / before | heavy imports before | heavy imports after |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        b, a = _med(r["seconds"]["before"]), _med(r["seconds"]["after"])
        imp = [", ".join(r["imports"][s]) or "none" for s in SIDES]
        lines.append(f"| `{r['command']}` | {b:.2f} | {a:.2f} | {a / b:.2f} | {imp[0]} | {imp[1]} |")
    return [*lines, ""]


def export_lines(commands: dict[str, dict[str, list[float]]], phases: dict[str, dict]) -> list[str]:
    lines = ["## Export", "", "| zoo model | before (s) | after (s) | after / before |", "|---|---|---|---|"]
    for model, t in commands.items():
        b, a = _med(t["before"]), _med(t["after"])
        lines.append(f"| {model} | {b:.1f} | {a:.1f} | {a / b:.2f} |")
    lines += ["", "Where one export process spends its time (code of `--after`, one run per model):", "",
              "| zoo model | step | seconds |", "|---|---|---|"]
    for model, p in phases.items():
        steps = p["steps"]
        lines.append(f"| {model} | whole process | {p['process']:.2f} |")
        lines += [f"| {model} | {step} | {sec:.2f} |" for step, sec in steps.items()]
        parts = [k for k in steps if k.startswith("import ")] + ["the export command after the imports"]
        rest = p["process"] - sum(steps.get(k, 0.0) for k in parts)
        lines.append(f"| {model} | the rest: interpreter start and exit | {rest:.2f} |")
    return [*lines, ""]


def variant_lines(variants: list[dict]) -> list[str]:
    lines = ["## Exporter variants", "",
             "| graph | variant | export (s) | ONNX nodes | parity max abs diff | onnxruntime (ms per batch) |",
             "|---|---|---|---|---|---|"]
    for v in variants:
        lines.append(f"| {v['graph']} | {v['variant']} | {_med(v['seconds']):.2f} | {v['nodes']} | "
                     f"{v['parity']:.1e} | {_med(v['ort_ms']):.1f} |")
    return [*lines, ""]


def measure_variants(tree: Path, repeats: int, work: Path) -> list[dict]:
    """The exporter variants per graph of the zoo's DepthNet and ContraFeat
    (:mod:`benchmarks.common.export_phases` ``--variants``)."""
    data = ensure_data(work)
    out = work / "variants.json"
    rows = []
    for model in ZOO_MODELS:
        subprocess.run([sys.executable, "-m", "benchmarks.common.export_phases", "--json", str(out), "--variants",
                        str(repeats), "--", *export_args(model, data, work / "out_variants")], cwd=tree,
                       env=_env(tree), check=True, capture_output=True)
        rows += json.loads(out.read_text())["variants"]
    return rows


def _arguments(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", type=Path, required=True, help="source tree of the reference code")
    ap.add_argument("--after", type=Path, default=ROOT, help="source tree of the changed code (default: this one)")
    ap.add_argument("--parts", nargs="+", default=["startup", "export", "variants"],
                    choices=["startup", "export", "variants"])
    ap.add_argument("--repeats", type=int, default=5, help="runs per start-up command and side")
    ap.add_argument("--export-repeats", type=int, default=3, help="export runs per model and side; variant repeats")
    ap.add_argument("--work", type=Path, default=WORK / "startup_export", help="data and output folder")
    ap.add_argument("--report", type=Path, default=STUDIES / "startup_export.md",
                    help="Markdown report; the JSON goes beside it (.json)")
    return ap.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    a = _arguments(argv)
    trees = {"before": a.before.resolve(), "after": a.after.resolve()}
    data: dict = {"trees": {s: _describe(t) for s, t in trees.items()}}
    body = [f"- before: `{data['trees']['before']}`, after: `{data['trees']['after']}`; {os.cpu_count()} CPUs, "
            f"load average {os.getloadavg()[0]:.1f} at the start; medians of alternating runs.", ""]
    if "startup" in a.parts:
        data["startup"] = measure_startup(trees, a.repeats, a.work)
        body += startup_lines(data["startup"])
    if "export" in a.parts:
        data["export"] = measure_export_commands(trees, a.export_repeats, a.work)
        data["phases"] = {m: measure_phases(trees["after"], m, a.work) for m in ZOO_MODELS}
        body += export_lines(data["export"], data["phases"])
    if "variants" in a.parts:
        data["variants"] = measure_variants(trees["after"], a.export_repeats, a.work)
        body += variant_lines(data["variants"])
    body.append(f"- load average {os.getloadavg()[0]:.1f} at the end.")
    Report(__file__, "Start-up of the commands and the phases of an ONNX export").publish(a.report, body, a, data)
    print(f"wrote {a.report}")
    return 0


def _describe(tree: Path) -> str:
    r = subprocess.run(["git", "describe", "--always", "--dirty"], cwd=tree, capture_output=True, text=True)
    return r.stdout.strip() or str(tree)


if __name__ == "__main__":
    raise SystemExit(main())
