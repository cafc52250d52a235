"""Fault injection: runs the bad-input table through the command lines and prints one row per case.

Each case runs as a subprocess on tiny data the script makes itself (simulator sequences of
10 frames at 128 px, a 1-step DepthNet and ContraFeat fit with configs/trainer/cpu_smoke.yaml
and configs/*/small.yaml, and their ONNX exports). A row gives the exit code, the number of
stderr lines and the last one ("traceback: ..." when stderr holds a traceback), and the output
folder before and after. The project's rule: bad input gives one line naming the file or
option and exit status 2, never destroying or mixing earlier outputs; Ctrl-C gives one line
and a defined state. Rows that break the rule are findings, not fixed here.

    python -m benchmarks.fault_injection --work /tmp/fault --report benchmarks/results/fault_injection.md
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from benchmarks.common.fault_run import Row, describe_folder, fingerprint, make_row, run_case, run_interrupted
from benchmarks.common.report import Report

PY = sys.executable
SLAM = [PY, "-m", "c3f_slam"]
MODELS = [PY, "-m", "c3f_models"]
SLAM_OPTIONS = ["--min-correspondences", "15", "--quiet"]
FRAMES, SIZE = 10, 128  # the tiny sequences: frames, square size in pixels
HEADER = ["| case | command | exit | stderr lines | last stderr line | OUT before | OUT after |",
          "|---|---|---|---|---|---|---|"]


@dataclass(frozen=True)
class Fixtures:
    """The data every case starts from, under ``work``: simulator sequences (``data/seq0..2``,
    and ``long/seq`` of 60 frames for the interrupt case) and, once :func:`build_models` ran,
    the fits (``fit_depth``, ``fit_feat``), their exports and a complete SLAM run (``base_run``)."""

    work: Path

    @property
    def data(self) -> Path:
        return self.work / "data"

    @property
    def seq(self) -> Path:
        return self.data / "seq0"

    @property
    def long_seq(self) -> Path:
        return self.work / "long" / "seq"

    def fit_run(self, kind: str) -> Path:
        """The TensorBoard run folder of the fit of ``kind`` (depth / feat)."""
        return self.work / f"fit_{kind}" / "tb" / "version_0"

    def ckpt(self, kind: str) -> Path:
        return self.fit_run(kind) / "checkpoints" / "last.ckpt"

    def export_dir(self, kind: str) -> Path:
        return self.work / f"export_{kind}"

    @property
    def depth_onnx(self) -> Path:
        return self.export_dir("depth") / "depthnet.onnx"

    @property
    def feat_onnx(self) -> Path:
        return self.export_dir("feat") / "contrafeat.onnx"

    @property
    def base_run(self) -> Path:
        return self.work / "base_run"

    def case_dir(self, name: str) -> Path:
        """A fresh folder for one case."""
        folder = self.work / "cases" / name
        if folder.exists():
            shutil.rmtree(folder)
        folder.mkdir(parents=True)
        return folder


def build_sequences(fx: Fixtures) -> None:
    """The simulator sequences (skipped when present)."""
    from datamodules.synthetic.fixture import make_tiny_sequence

    for k in range(3):
        if not (fx.data / f"seq{k}" / "camera.json").is_file():
            make_tiny_sequence(fx.data / f"seq{k}", frames=FRAMES, size=SIZE, seed=k)
    if not (fx.long_seq / "camera.json").is_file():
        make_tiny_sequence(fx.long_seq, frames=60, size=SIZE, seed=5)


def fit_command(fx: Fixtures, kind: str, root: Path, steps: int = 1) -> list[str]:
    """A smoke fit of ``kind`` (depth / feat) on ``fx.data`` logging under ``root``."""
    config = "configs/depthnet/small.yaml" if kind == "depth" else "configs/contrafeat/small.yaml"
    return [*MODELS, "fit", "--config", "configs/trainer/cpu_smoke.yaml", "--config", config,
            "--data.data_dir", str(fx.data), "--trainer.max_steps", str(steps),
            "--trainer.default_root_dir", str(root), "--trainer.logger.init_args.save_dir", str(root),
            "--trainer.enable_progress_bar", "false"]


def export_command(config: Path, ckpt: Path, out: Path) -> list[str]:
    return [*MODELS, "export", "--config", str(config), "--ckpt_path", str(ckpt), "--output_dir", str(out)]


def _check(cmd: list[str]) -> None:
    from benchmarks.common.fault_run import run_to_end

    done = run_to_end(cmd)
    if done.exit_code != 0:
        raise SystemExit(f"fixture command failed ({done.exit_code}): {' '.join(cmd)}\n{done.stderr[-2000:]}")


def build_models(fx: Fixtures) -> None:
    """The 1-step fits, their exports and a complete SLAM run (each skipped when present)."""
    for kind in ("depth", "feat"):
        if not fx.ckpt(kind).is_file():
            _check(fit_command(fx, kind, fx.work / f"fit_{kind}"))
        if not fx.export_dir(kind).is_dir():
            _check(export_command(fx.fit_run(kind) / "config.yaml", fx.ckpt(kind), fx.export_dir(kind)))
    if not (fx.base_run / "summary.json").is_file():
        _check([*SLAM, "run", str(fx.seq), "--out", str(fx.base_run), *SLAM_OPTIONS])


def _copy_seq(fx: Fixtures, folder: Path) -> Path:
    seq = folder / "seq"
    shutil.copytree(fx.seq, seq)
    return seq


def _copy_base_run(fx: Fixtures, folder: Path) -> Path:
    out = folder / "out"
    shutil.copytree(fx.base_run, out)
    return out


# ---------------------------------------------------------------------------------------- c3f_slam


def slam_missing_sequence(fx: Fixtures) -> Row:
    folder = fx.case_dir("slam_missing")
    out = folder / "out"
    return run_case("run: missing sequence folder", [*SLAM, "run", str(folder / "nowhere"), "--out", str(out),
                                                     *SLAM_OPTIONS], fx.work, out)


def _corrupt_png(fx: Fixtures, folder: Path) -> Path:
    seq = _copy_seq(fx, folder)
    sorted((seq / "rgb").iterdir())[3].write_bytes(b"\x89PNG damaged")
    return seq


def slam_corrupt_png(fx: Fixtures) -> Row:
    folder = fx.case_dir("slam_corrupt_png")
    seq, out = _corrupt_png(fx, folder), folder / "out"
    row = run_case("run: corrupt rgb PNG (frame 3), default policy", [*SLAM, "run", str(seq), "--out", str(out),
                                                                        "--no-mesh", *SLAM_OPTIONS], fx.work, out)
    summary = out / "summary.json"
    skipped = json.loads(summary.read_text()).get("skipped_unreadable") if summary.is_file() else None
    return Row(row.case, row.command, row.exit_code, row.stderr_lines, row.last_line, row.before,
               f"{row.after}, skipped_unreadable {skipped}")


def slam_corrupt_png_strict(fx: Fixtures) -> Row:
    folder = fx.case_dir("slam_corrupt_png_strict")
    seq, out = _corrupt_png(fx, folder), folder / "out"
    return run_case("run: corrupt rgb PNG, --max-bad-frames 0",
                    [*SLAM, "run", str(seq), "--out", str(out), "--no-mesh", "--max-bad-frames", "0", *SLAM_OPTIONS],
                    fx.work, out)


def slam_wrong_intrinsics(fx: Fixtures) -> Row:
    folder = fx.case_dir("slam_wrong_intrinsics")
    seq, out = _copy_seq(fx, folder), folder / "out"
    camera = json.loads((seq / "camera.json").read_text())
    camera.update(width=2 * SIZE, height=2 * SIZE)
    (seq / "camera.json").write_text(json.dumps(camera))
    return run_case(f"run: camera.json {2 * SIZE}x{2 * SIZE}, frames {SIZE}x{SIZE}",
                    [*SLAM, "run", str(seq), "--out", str(out), *SLAM_OPTIONS], fx.work, out)


def slam_nan_poses(fx: Fixtures) -> Row:
    folder = fx.case_dir("slam_nan_poses")
    seq, out = _copy_seq(fx, folder), _copy_base_run(fx, folder)
    lines = (seq / "poses.txt").read_text().splitlines()
    fields = lines[3].split()
    lines[3] = " ".join([fields[0], "nan", *fields[2:]])
    (seq / "poses.txt").write_text("\n".join(lines) + "\n")
    return run_case("evaluate: NaN in the ground truth's poses.txt", [*SLAM, "evaluate", str(out), "--gt", str(seq)],
                    fx.work, out)


def slam_depth_model_wrong_kind(fx: Fixtures) -> Row:
    out = fx.case_dir("slam_wrong_kind") / "out"
    return run_case("run: --depth-model given a ContraFeat ONNX",
                    [*SLAM, "run", str(fx.seq), "--depth-model", str(fx.feat_onnx), "--out", str(out), *SLAM_OPTIONS],
                    fx.work, out)


def slam_garbage_onnx(fx: Fixtures) -> Row:
    folder = fx.case_dir("slam_garbage_onnx")
    model, out = folder / "garbage.onnx", folder / "out"
    model.write_bytes(b"not an onnx model\x00" * 64)
    return run_case("run: --depth-model a garbage .onnx",
                    [*SLAM, "run", str(fx.seq), "--depth-model", str(model), "--out", str(out), *SLAM_OPTIONS],
                    fx.work, out)


def slam_truncated_video(fx: Fixtures) -> Row:
    import cv2

    folder = fx.case_dir("slam_truncated_video")
    video, out = folder / "clip.avi", folder / "out"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (SIZE, SIZE))
    for frame in sorted((fx.seq / "rgb").glob("*.png")):
        writer.write(cv2.imread(str(frame)))
    writer.release()
    data = video.read_bytes()
    video.write_bytes(data[: len(data) // 2])
    shutil.copy(fx.seq / "camera.json", folder / "camera.json")
    return run_case("run: video cut at half its bytes, --depth-model",
                    [*SLAM, "run", str(video), "--depth-model", str(fx.depth_onnx), "--out", str(out), "--no-mesh",
                     *SLAM_OPTIONS], fx.work, out)


def slam_second_run(fx: Fixtures) -> Row:
    out = _copy_base_run(fx, fx.case_dir("slam_second_run"))
    return run_case("run: into a folder holding a complete run, no --overwrite",
                    [*SLAM, "run", str(fx.seq), "--out", str(out), *SLAM_OPTIONS], fx.work, out)


def slam_sigint(fx: Fixtures) -> Row:
    folder = fx.case_dir("slam_sigint")
    out = _copy_base_run(fx, folder)
    cmd = [*SLAM, "run", str(fx.long_seq), "--out", str(out), "--overwrite", *SLAM_OPTIONS]
    before, before_text = fingerprint(out), describe_folder(out)

    def started() -> bool:  # the run builds its folder beside OUT
        return any(p.name.startswith(".out.") for p in folder.iterdir())

    done = run_interrupted(cmd, started, delay_s=1.0)
    return make_row("run: SIGINT 1 s into a 60-frame run, --overwrite over a complete run", cmd, fx.work, out, done,
                    before_text, before)


# ---------------------------------------------------------------------------------------- c3f_models


def _export_case(fx: Fixtures, case: str, name: str, ckpt_bytes: Callable[[], bytes] | None = None,
                 ckpt: Path | None = None) -> Row:
    """Export with the DepthNet run's config and a bad checkpoint into a copy of a good export."""
    folder = fx.case_dir(name)
    out = folder / "out"
    shutil.copytree(fx.export_dir("depth"), out)
    if ckpt is None:
        ckpt = folder / "bad.ckpt"
        ckpt.write_bytes(ckpt_bytes() if ckpt_bytes else b"")
    return run_case(case, export_command(fx.fit_run("depth") / "config.yaml", ckpt, out), fx.work, out)


def export_garbage_ckpt(fx: Fixtures) -> Row:
    return _export_case(fx, "export: --ckpt_path a garbage file", "export_garbage", lambda: b"garbage\n" * 100)


def export_truncated_ckpt(fx: Fixtures) -> Row:
    data = fx.ckpt("depth").read_bytes()
    return _export_case(fx, "export: checkpoint cut at half its bytes", "export_truncated",
                        lambda: data[: len(data) // 2])


def export_other_class(fx: Fixtures) -> Row:
    return _export_case(fx, "export: ContraFeat checkpoint, DepthNet config", "export_other_class",
                        ckpt=fx.ckpt("feat"))


def _fit_case(fx: Fixtures, case: str, name: str, extra: list[str], steps: int = 1) -> Row:
    """A fit with ``extra`` options logging into a fresh folder; the row describes that folder."""
    root = fx.case_dir(name) / "runs"
    return run_case(case, [*fit_command(fx, "depth", root, steps), *extra], fx.work, root)


class _Payload:
    """Unpickling this creates the file ``marker`` (a stand-in for arbitrary code)."""

    def __init__(self, marker: Path):
        self.marker = str(marker)

    def __reduce__(self):
        return open, (self.marker, "w")


def fit_payload_init_weights(fx: Fixtures) -> Row:
    import torch

    folder = fx.case_dir("fit_payload")
    marker, weights = folder / "PAYLOAD_RAN", folder / "payload.ckpt"
    torch.save({"state_dict": {"x": _Payload(marker)}}, weights)
    row = _fit_case(fx, "fit: --model.init_args.init_weights a pickle with a payload", "fit_payload_run",
                    ["--model.init_args.init_weights", str(weights)])
    ran = "PAYLOAD RAN (marker file exists)" if marker.exists() else "payload did not run"
    return Row(row.case, row.command, row.exit_code, row.stderr_lines, row.last_line, row.before,
               f"{row.after}; {ran}")


def fit_batch_size_zero(fx: Fixtures) -> Row:
    return _fit_case(fx, "fit: --data.loader.batch_size 0", "fit_batch0", ["--data.loader.batch_size", "0"])


def fit_missing_pretrained(fx: Fixtures) -> Row:
    return _fit_case(fx, "fit: --model.network.pretrained_path a missing file", "fit_pretrained",
                     ["--model.network.pretrained_path", str(fx.work / "missing.pth")])


def fit_resume_conflict(fx: Fixtures) -> Row:
    folder = fx.case_dir("fit_resume")
    root = folder / "runs"
    shutil.copytree(fx.work / "fit_depth", root)
    ckpt = root / "tb" / "version_0" / "checkpoints" / "last.ckpt"
    cmd = [*fit_command(fx, "depth", root, 2), "--ckpt_path", str(ckpt), "--model.loss.lambda_dc", "0.5"]
    return run_case("fit: resume with a conflicting --model.loss.lambda_dc", cmd, fx.work, root)


def fit_sigint(fx: Fixtures) -> Row:
    root = fx.case_dir("fit_sigint") / "runs"
    cmd = [*fit_command(fx, "depth", root, 1000), "--trainer.limit_train_batches", "1000"]

    def started() -> bool:  # the config is saved when training starts
        return (root / "tb" / "version_0" / "config.yaml").is_file()

    done = run_interrupted(cmd, started, delay_s=5.0)
    ckpts = sorted(p.name for p in root.rglob("*.ckpt")) if root.exists() else []
    row = make_row("fit: SIGINT 5 s after training started", cmd, fx.work, root, done, "nothing written", {})
    left = f"checkpoints left: {', '.join(ckpts)}" if ckpts else "no checkpoint left"
    return Row(row.case, row.command, row.exit_code, row.stderr_lines, row.last_line, row.before,
               f"{row.after}; {left}")


# ---------------------------------------------------------------------------------------- datamodules


def convert_missing_folder(fx: Fixtures) -> Row:
    folder = fx.case_dir("convert_missing")
    out = folder / "out"
    return run_case("convert: missing source folder", [PY, "-m", "datamodules", "convert", "uts",
                                                       str(folder / "nowhere"), "--out", str(out), "--no-progress"],
                    fx.work, out)


def convert_other_layout(fx: Fixtures) -> Row:
    out = fx.case_dir("convert_other_layout") / "out"
    return run_case("convert: c3vd given a folder in the project's layout",
                    [PY, "-m", "datamodules", "convert", "c3vd", str(fx.data), "--out", str(out), "--no-progress"],
                    fx.work, out)


#: Cases that need only the simulator sequences (cheap: no torch in the subprocess, no models).
DATA_CASES: list[Callable[[Fixtures], Row]] = [
    slam_missing_sequence, slam_corrupt_png, slam_corrupt_png_strict, slam_wrong_intrinsics,
    convert_missing_folder, convert_other_layout]
#: Cases that need the fits, exports and the complete SLAM run of :func:`build_models`.
MODEL_CASES: list[Callable[[Fixtures], Row]] = [
    slam_nan_poses, slam_depth_model_wrong_kind, slam_garbage_onnx, slam_truncated_video, slam_second_run,
    slam_sigint, export_garbage_ckpt, export_truncated_ckpt, export_other_class, fit_payload_init_weights,
    fit_batch_size_zero, fit_missing_pretrained, fit_resume_conflict, fit_sigint]


def run_table(fx: Fixtures, echo: bool = True) -> list[Row]:
    """Every case, in table order (building what they need first)."""
    build_sequences(fx)
    build_models(fx)
    rows = []
    for case in [*DATA_CASES[:4], *MODEL_CASES, *DATA_CASES[4:]]:
        rows.append(case(fx))
        if echo:
            print(rows[-1].markdown(), flush=True)
    return rows


def report_body(rows: list[Row]) -> list[str]:
    """The report's text after its command line: what the table holds, then the table."""
    return ["One row per case, each run as a subprocess on data the script made itself (simulator sequences "
            f"of {FRAMES} frames at {SIZE} px, 1-step DepthNet / ContraFeat fits of the small configs and their ONNX "
            "exports). `W` is the `--work` folder; `[smoke X]` stands for `--config configs/trainer/cpu_smoke.yaml "
            "--config configs/X/small.yaml --data.data_dir W/data` and the case's own logging folder. Stderr lines "
            "count everything, Lightning's info lines (`Seed set to 42`, ...) included; each case's stderr is kept "
            "in `W/cases/<case>/stderr.txt`. Expected: exit 2 with one `error:` line naming the file or "
            "option, OUT unchanged or nothing written; SIGINT: one line, exit 130, a defined state.",
            "", *HEADER, *(r.markdown() for r in rows)]


def _arguments(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--work", type=Path, required=True, help="scratch folder for the data, models and cases")
    ap.add_argument("--report", type=Path, default=None, help="write the table to this markdown file")
    return ap.parse_args(argv)


def main(argv: list[str] | None = None) -> None:
    args = _arguments(argv)
    rows = run_table(Fixtures(args.work.resolve()))
    if args.report is not None:
        report = Report(__file__, "Fault injection: the bad-input table", argv)
        report.write(args.report, report.render(report_body(rows)))


if __name__ == "__main__":
    main()
