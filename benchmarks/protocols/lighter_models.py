"""Lighter models: the zoo's DepthNet and ContraFeat exported in float32, float16 and int8, side
by side in one run: file size, parity, latency, held-out depth metrics, match precision / recall,
and a monocular SLAM run with each precision's pair of files.

Every file is made here with the project's exporter (``python -m c3f_models export --precision
P``) from the zoo's weights; int8 is calibrated on two of the zoo's training sequences
(seq1_s1001, seq3_s1006, 64 frames). The held-out numbers come from the zoo's held-out
sequences (other seeds, seq5's appearance unseen in training):

- depth: the zoo card's protocol (:func:`c3f_models.zoo.evaluate.depth_heldout`): Abs Rel and
  delta < 1.25 with per-image median scaling, and the metric scale error without it;
- matches: the zoo card's protocol (:func:`c3f_models.zoo.evaluate.descriptor_heldout`), with the
  network replaced by the ONNX file's dense graph on onnxruntime: recall and precision of
  ContraFeat and ContraFeat+kpf matches;
- SLAM: ``python -m c3f_slam run SEQ --depth-model depthnet.onnx --feature-model contrafeat.onnx``
  (the runtime takes the keypoint graph beside it), ATE after Sim(3) alignment, registered share
  and frames/s;
- latency: onnxruntime on one 128 px frame at batch 1 (the keypoint graph with 300 keypoints),
  1 and 2 threads, the precisions alternating, medians.

    python -m benchmarks.protocols.lighter_models
    python -m benchmarks.protocols.lighter_models --set repeats=10 --set slam_repeats=1 --report /tmp/lighter.md

Inputs: sequences generated under ``--work`` (default ``runs/bench/lighter_models``); the zoo's
weights. Writes benchmarks/results/lighter_models.md and its .json. Settings (``--print-config``:
each with its default and meaning): :class:`Settings`.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from benchmarks.common import RESULTS, ROOT, WORK
from benchmarks.common.protocol_cli import REPORT_HELP, WORK_HELP, ProtocolCli
from benchmarks.common.report import Report
from benchmarks.common.slam_run import run_and_score
from c3f_models.zoo.recipes import HELD_OUT, TRAIN
from c3f_models.zoo.train import simulate

PRECISIONS = ("float32", "float16", "int8")
DEPTH, FEATURES = "c3f-depth-r18w32", "c3f-features-r18w32"
GRAPHS = {DEPTH: "[depth]", FEATURES: "[descriptors,descriptors_kp]"}
FILES = {DEPTH: ("depthnet.onnx",), FEATURES: ("contrafeat.onnx", "contrafeat_kp.onnx")}
CALIBRATION = ("seq1_s1001", "seq3_s1006")


def sequences(work: Path, heldout: int) -> tuple[Path, list[Path]]:
    """(calibration data folder, held-out sequence folders), generated once under ``work``."""
    cal = [s for s in TRAIN if s.name in CALIBRATION]
    simulate(tuple(cal), 128, work / "calibration")
    return work / "calibration", simulate(HELD_OUT[:heldout], 128, work / "heldout")


def export(name: str, precision: str, cal: Path, parity_seq: Path, out: Path) -> dict:
    """Export zoo entry ``name`` in ``precision`` into ``out`` with the CLI; export.json plus the wall time."""
    entry = ROOT / "zoo" / name
    cmd = [sys.executable, "-m", "c3f_models", "export", "--config", str(entry / "config.yaml"),
           "--ckpt_path", str(entry / "weights.safetensors"), "--data.data_dir", str(cal),
           "--output_dir", str(out), "--graphs", GRAPHS[name], "--precision", precision,
           "--frames", str(parity_seq), "--calibration_frames", "64"]
    t0 = time.perf_counter()
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"export {name} {precision} failed: {(done.stderr.strip().splitlines() or ['?'])[-1]}")
    manifest = json.loads((out / "export.json").read_text())
    manifest["export_seconds"] = time.perf_counter() - t0
    return manifest


def latencies(files: dict[str, Path], frame: np.ndarray, repeats: int) -> dict[str, dict[int, float]]:
    """Median ms per call of each file at 1 and 2 threads, the files alternating."""
    import onnxruntime as ort

    rng = np.random.default_rng(0)
    points = (rng.random((1, 300, 2)) * (np.array(frame.shape[-1:-3:-1]) - 1)).astype(np.float32)
    out: dict[str, dict[int, float]] = {k: {} for k in files}
    for threads in (1, 2):
        sessions = {}
        for key, path in files.items():
            opts = ort.SessionOptions()
            opts.intra_op_num_threads, opts.log_severity_level = threads, 3
            sessions[key] = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
        times: dict[str, list[float]] = {k: [] for k in files}
        for i in range(repeats + 3):
            for key, s in sessions.items():
                feed = {"image": frame, **({"keypoints": points} if len(s.get_inputs()) == 2 else {})}
                t0 = time.perf_counter()
                s.run(None, feed)
                if i >= 3:
                    times[key].append(time.perf_counter() - t0)
        for key in files:
            out[key][threads] = 1000 * statistics.median(times[key])
    return out


class OnnxDescriptorNet:
    """The dense descriptor graph on onnxruntime in place of ContraFeat's network: (B, 3, H, W)
    tensor in [0, 1] -> (B, C, H, W) tensor."""

    def __init__(self, path: Path, threads: int = 2) -> None:
        import onnxruntime as ort

        opts = ort.SessionOptions()
        opts.intra_op_num_threads, opts.log_severity_level = threads, 3
        self.session = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])

    def __call__(self, images):
        import torch

        return torch.from_numpy(self.session.run(None, {"image": images.detach().cpu().numpy()})[0])


def match_metrics(dense: Path, heldout: list[Path]) -> dict:
    """The zoo card's match evaluation with the ONNX dense graph as the network."""
    import torch

    from c3f_models.contrafeat.module import ContraFeat
    from c3f_models.zoo.evaluate import descriptor_heldout

    cfg = yaml.safe_load((ROOT / "zoo" / FEATURES / "config.yaml").read_text())["model"]["init_args"]
    model = ContraFeat(**{k: v for k, v in cfg.items() if k != "init_weights"}).eval()
    net = OnnxDescriptorNet(dense)
    model.net.forward = net  # the module keeps its attributes; its computation is the ONNX file's
    with torch.no_grad():
        return descriptor_heldout(model, heldout[0].parent, [p.name for p in heldout])["mean"]


def slam(depth: Path, feat: Path, seq: Path, out: Path) -> dict:
    """One monocular run with these files: ATE (Sim(3), cm and % of the path), registered share, frames/s."""
    cmd = [sys.executable, "-m", "c3f_slam", "run", str(seq), "--out", str(out), "--overwrite", "--quiet",
           "--depth-model", str(depth), "--feature-model", str(feat), "--set", "coverage.enabled=false"]
    s, ev = run_and_score(cmd, out, seq, f"slam {out.name}")
    rmse = ev.get("ate_sim3", {}).get("rmse_m", float("nan"))
    return {"ate_cm": 100 * rmse, "ate_percent_of_path": 100 * rmse / ev["gt_length_m"],
            "registered_share": s["registered_share"], "fps": s["frames"] / s["wall_seconds"],
            "descriptor_file": s.get("models", {}).get("descriptors", {}).get("file")}


@dataclass(frozen=True)
class Settings:
    """What lighter_models measures."""

    heldout: int = 6  #: held-out sequences of the zoo's six (depth, matches)
    match_sequences: int = 3  #: of those, how many the match evaluation uses (every other: one per preset)
    repeats: int = 30  #: timed calls per file and thread count
    slam_repeats: int = 3  #: SLAM runs per precision (alternating)


CLI = ProtocolCli("lighter_models", Settings, __doc__, example="repeats=10")


def parse_args(argv: list[str] | None = None) -> tuple[argparse.Namespace, Settings]:
    """The plain options (work folder, report) and the settings of ``argv``."""
    ap = CLI.parser()
    ap.add_argument("--work", type=Path, default=WORK / "lighter_models", help=WORK_HELP)
    ap.add_argument("--report", type=Path, default=RESULTS / "lighter_models.md", help=REPORT_HELP)
    return CLI.parse(ap, argv)


def main(argv: list[str] | None = None) -> None:
    from c3f_models.zoo.evaluate import depth_heldout

    args, settings = parse_args(argv)
    cal, heldout = sequences(args.work, settings.heldout)
    data: dict[str, dict] = {}
    for p in PRECISIONS:
        d = {name: export(name, p, cal, heldout[0], args.work / "exports" / p / name) for name in (DEPTH, FEATURES)}
        folder = args.work / "exports" / p
        d["depth_metrics"] = depth_heldout(folder / DEPTH / "depthnet.onnx", heldout)
        d["match_metrics"] = match_metrics(folder / FEATURES / "contrafeat.onnx",
                                           heldout[::2][:settings.match_sequences])
        data[p] = d
        print(f"{p}: exported and evaluated", flush=True)
    for p, runs in slam_runs(settings, args.work, heldout[0]).items():  # the precisions alternate: noise hits all alike
        data[p]["slam"] = {**runs[0], "fps": statistics.median(r["fps"] for r in runs),
                           "fps_runs": [r["fps"] for r in runs], "ate_cm_runs": [r["ate_cm"] for r in runs]}
    files = {f"{p}/{f}": args.work / "exports" / p / name / f
             for p in PRECISIONS for name in FILES for f in FILES[name]}
    lat = latencies(files, _frame(heldout[0]), settings.repeats)
    for key, v in lat.items():
        p, f = key.split("/")
        data[p].setdefault("latency_ms", {})[f] = v
        data[p].setdefault("bytes", {})[f] = files[key].stat().st_size
    Report(__file__, "Lighter models: float32, float16 and int8 exports of the zoo").publish(
        args.report, body(settings, data), settings, data, options=args)


def slam_runs(settings: Settings, work: Path, seq: Path) -> dict[str, list[dict]]:
    """``settings.slam_repeats`` runs per precision on ``seq`` (exports and runs in ``work``), the precisions
    alternating."""
    runs: dict[str, list[dict]] = {p: [] for p in PRECISIONS}
    for _ in range(settings.slam_repeats):
        for p in PRECISIONS:
            folder = work / "exports" / p
            runs[p].append(slam(folder / DEPTH / "depthnet.onnx", folder / FEATURES / "contrafeat.onnx", seq,
                                work / "runs" / p))
    return runs


def _frame(seq: Path) -> np.ndarray:
    """The sequence's middle frame as the depth network's (1, 3, 128, 128) input."""
    from c3f_slam.frames.preprocess import prepare_network_input
    from c3f_slam.io import Sequence

    s = Sequence(seq)
    rgb, _, _ = prepare_network_input(s.read_rgb(len(s) // 2), s.camera, crop=None, size=(128, 128), specular=True)
    return (np.ascontiguousarray(rgb).transpose(2, 0, 1)[None] / 255.0).astype(np.float32)


def tables(data: dict) -> list[str]:
    """The report's tables: files, then the held-out effect."""
    rows = ["| precision | file | MB | export s | parity: max abs diff | mean abs / mean magnitude | "
            "ms, 1 thread | ms, 2 threads | speed-up vs float32, 1 / 2 threads |",
            "|---|---|---|---|---|---|---|---|---|"]
    for p in PRECISIONS:
        for name in (DEPTH, FEATURES):
            for f in FILES[name]:
                par, lat = data[p][name]["files"][f]["parity"], data[p]["latency_ms"][f]
                ref = data["float32"]["latency_ms"][f]
                rows.append(f"| {p} | {f} | {data[p]['bytes'][f] / 1e6:.1f} | {data[p][name]['export_seconds']:.0f} | "
                            f"{par['max_abs_diff']:.2g} | {par.get('relative_mean_diff', float('nan')):.2g} | "
                            f"{lat[1]:.1f} | {lat[2]:.1f} | {ref[1] / lat[1]:.2f}x / {ref[2] / lat[2]:.2f}x |")
    rows += ["", "| precision | Abs Rel | δ<1.25 | metric scale error | CDF recall / precision % | "
             "CDF+kpf recall / precision % | SLAM ATE cm (% of path) | registered % | SLAM frames/s (median) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for p in PRECISIONS:
        d, m, s = data[p]["depth_metrics"], data[p]["match_metrics"], data[p]["slam"]
        rows.append(f"| {p} | {d['mean']['abs_rel']:.4f} | {d['mean']['a1']:.4f} | {d['median_scale_error']:.4f} | "
                    f"{100 * m['cdf_recall']:.1f} / {100 * m['cdf_precision']:.1f} | "
                    f"{100 * m['cdf_kpf_recall']:.1f} / {100 * m['cdf_kpf_precision']:.1f} | "
                    f"{s['ate_cm']:.2f} ({s['ate_percent_of_path']:.2f}) | {100 * s['registered_share']:.1f} | "
                    f"{s['fps']:.1f} |")
    return rows


def body(settings: Settings, data: dict) -> list[str]:
    return [
        f"- Machine: {os.cpu_count()} CPU cores ({platform.machine()}, "
        f"{'AVX512-VNNI' if _has_vnni() else 'no VNNI'}), no GPU, shared with other jobs.",
        f"- Models: the zoo's {DEPTH} and {FEATURES} (128 px), exported here from their weights; int8 "
        f"calibrated on {', '.join(CALIBRATION)} (training sequences, 64 frames).",
        f"- Held out: {', '.join(p.name for p in HELD_OUT[:settings.heldout])} (depth); matches on every other "
        f"one, {settings.match_sequences} sequences; SLAM on {HELD_OUT[0].name}, {settings.slam_repeats} runs per "
        "precision, the precisions alternating (ATE and registered share of the first run; every run's ATE in the "
        "JSON).",
        "",
        *tables(data),
    ]


def _has_vnni() -> bool:
    try:
        return "avx512_vnni" in Path("/proc/cpuinfo").read_text() or "avx_vnni" in Path("/proc/cpuinfo").read_text()
    except OSError:
        return False


if __name__ == "__main__":
    main()
