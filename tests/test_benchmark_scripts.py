"""Every benchmark script at least parses its command line (imports and module-level code
run): benchmarks run outside CI, so a broken script would otherwise go unnoticed. Scripts run
from the repository root as modules (``python -m benchmarks.protocols.NAME``, ``python -m
benchmarks.studies.NAME``), as benchmarks/README.md says. Every protocol publishes its report as
Markdown and JSON (``Report.publish``) and runs with no path given."""

from __future__ import annotations

import argparse
import ast
import importlib
import subprocess
import sys
from pathlib import Path

import pytest

from benchmarks.common import RESULTS, WORK
from benchmarks.common.report import END, Report

pytestmark = pytest.mark.e2e  # every test here runs the project's commands end to end

ROOT = Path(__file__).resolve().parents[1]
FOLDERS = ("protocols", "studies")  #: the script folders of benchmarks/
SCRIPTS = sorted(p for folder in FOLDERS for p in (ROOT / "benchmarks" / folder).glob("*.py") if p.stem != "__init__")
PROTOCOLS = [p for p in SCRIPTS if p.parent.name == "protocols"]
#: the arguments a protocol may require: named inputs, never scratch data (trajectory_identity: the
#: source tree of the code compared with)
REQUIRED_INPUTS = {"trajectory_identity": {"before"}}


def _module(script: Path) -> list[str]:
    return [sys.executable, "-m", ".".join(script.relative_to(ROOT).with_suffix("").parts)]


def test_there_are_benchmarks():
    assert len(SCRIPTS) >= 5


@pytest.mark.parametrize("script", SCRIPTS, ids=[s.stem for s in SCRIPTS])
def test_help(script: Path):
    r = subprocess.run([*_module(script), "--help"], cwd=ROOT, capture_output=True, text=True, timeout=120,
                       check=False)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "usage:" in r.stdout


class _Parsed(Exception):
    """Raised in place of parsing: the protocol's parser is built, nothing has run."""


def _parser_of(module, monkeypatch) -> argparse.ArgumentParser:
    """The option parser that the protocol ``module``'s main() builds (stopped at parse_args)."""
    built: list[argparse.ArgumentParser] = []

    def parse_args(self, args=None, namespace=None):
        built.append(self)
        raise _Parsed

    monkeypatch.setattr(argparse.ArgumentParser, "parse_args", parse_args)
    monkeypatch.setattr(sys, "argv", [module.__name__])
    with pytest.raises(_Parsed):
        module.main()
    return built[0]


def _inside_repository(value) -> bool:
    return not isinstance(value, (str, Path)) or not Path(value).is_absolute() or Path(value).is_relative_to(ROOT)


def test_protocols_and_studies():
    assert {p.stem for p in PROTOCOLS} >= {"slam_ate", "slam_tracking", "coverage_accuracy", "zoo", "simulator_fps"}
    assert (ROOT / "benchmarks" / "studies" / "depthnet_gradients.py").is_file()


@pytest.mark.parametrize("script", PROTOCOLS, ids=[s.stem for s in PROTOCOLS])
def test_protocol_publishes_json_and_needs_no_path(script: Path, monkeypatch):
    """A protocol writes its report through Report.publish (Markdown and the JSON beside it, never
    the Markdown alone), and runs with no argument: it requires none (its data are regenerated or
    named), its work folder defaults to runs/bench/NAME and no default path leaves the repository
    (no scratch folder)."""
    calls = {node.func.attr for node in ast.walk(ast.parse(script.read_text()))
             if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)}
    assert "publish" in calls and not calls & {"write", "render"}, "write the report with Report.publish"
    parser = _parser_of(importlib.import_module(f"benchmarks.protocols.{script.stem}"), monkeypatch)
    actions = {a.dest: a for a in parser._actions if a.dest != "help"}
    required = {dest for dest, a in actions.items() if a.required} - REQUIRED_INPUTS.get(script.stem, set())
    assert not required, f"required arguments: {sorted(required)}"
    if "work" in actions:
        assert actions["work"].default == WORK / script.stem
    assert all(_inside_repository(a.default) for a in actions.values()), {d: a.default for d, a in actions.items()}
    reports = [Path(a.default) for a in actions.values() if str(a.default).endswith(".md")]
    assert all(r.parent == RESULTS for r in reports), reports  # the recorded results, not a scratch copy


def test_tracking_breaks_reports_a_black_frame(tmp_path):
    """benchmarks/studies/slam_tracking_breaks.py on a tiny sequence with one black frame: the two
    pairs around it are the only broken ones, the report says why and, given the run, that the
    black frame is not registered while the frame after it is in the main map."""
    import cv2
    import numpy as np

    from datamodules.synthetic.fixture import make_tiny_sequence

    seq = make_tiny_sequence(tmp_path / "seq", frames=20, size=128, seed=3)
    frame = sorted((seq / "rgb").iterdir())[10]
    cv2.imwrite(str(frame), np.zeros((128, 128, 3), np.uint8))
    run = tmp_path / "run"
    r = subprocess.run([sys.executable, "-m", "c3f_slam", "run", str(seq), "--out", str(run),
                        "--set", "fusion.enabled=false"],
                       cwd=ROOT, capture_output=True, text=True, timeout=300, check=False)
    assert r.returncode == 0, r.stderr[-2000:]
    report = tmp_path / "breaks.md"
    r = subprocess.run([*_module(ROOT / "benchmarks" / "studies" / "slam_tracking_breaks.py"), str(seq), "--run",
                        str(run), "--report", str(report)], cwd=ROOT, capture_output=True, text=True, timeout=300,
                       check=False)
    assert r.returncode == 0, r.stderr[-2000:]
    text = report.read_text()
    assert "Broken pairs (no accepted match): 2;" in text, text
    assert "| 10 | - | 0 |" in text and "| 11 | - |" in text and "too few keypoints" in text
    rows = {line.split(" | ")[0]: line for line in text.splitlines() if line.startswith(("| 10 |", "| 11 |"))}
    assert rows["| 10"].endswith("| 0 | not registered |") and rows["| 11"].endswith("| main |"), rows
    assert "frame i of the 2 broken pairs is: main 1, not registered 1." in text


def test_depth_motion_measures_a_known_scale(tmp_path):
    """benchmarks/studies/depth_motion.py on a "network" that predicts a quarter of the true depth:
    scale 0.25, depth changes that follow the true ones, translations a quarter of the true
    ones in the right direction; the true-depth control recovers the motion."""
    from benchmarks.studies import depth_motion
    from c3f_slam.io import Sequence
    from datamodules.synthetic.fixture import make_tiny_sequence

    seq = Sequence(make_tiny_sequence(tmp_path / "seq", frames=16, size=64, seed=2))
    res = depth_motion.analyse(seq, lambda i: 0.25 * seq.read_depth(i), [0, 4, 8], [1, 3])
    assert res["scale_median"] == pytest.approx(0.25) and res["scale_cv"] == pytest.approx(0.0, abs=1e-9)
    for gap in (1, 3):
        r = res["gaps"][gap]
        assert r["pairs"] == 3 and r["points"] > 100
        assert 0.9 < r["slope"] < 1.1 and r["corr"] > 0.9
        assert r["ratio"] == pytest.approx(0.25, rel=0.1) and r["cos"] > 0.99
        assert r["ratio_gt"] == pytest.approx(1.0, rel=0.05) and r["cos_gt"] > 0.99
        assert r["scale_jump"] == pytest.approx(0.0, abs=1e-9)


def test_contrafeat_match_image_stacks_one_row_per_checkpoint(plane_dataset, tmp_path):
    """benchmarks/studies/contrafeat_match_image.py on a plane sequence with two (untrained) checkpoints:
    one 2x-scaled side-by-side row per checkpoint, and a line of counts for each."""
    import cv2
    import torch

    from benchmarks.common.contrafeat import SMALL_MODEL
    from c3f_models.contrafeat.module import ContraFeat

    ckpts = []
    for k in range(2):
        torch.manual_seed(k)
        ckpts.append(tmp_path / f"m{k}.ckpt")
        torch.save({"state_dict": ContraFeat(**SMALL_MODEL).state_dict(), "global_step": 0}, ckpts[-1])
    out = tmp_path / "img" / "matches.png"
    r = subprocess.run([*_module(ROOT / "benchmarks" / "studies" / "contrafeat_match_image.py"), "--data",
                        str(plane_dataset), "--seq", "plane0", "--gap", "1", "--size", "48", "--pair", "0",
                        "--checkpoint", str(ckpts[0]), "--checkpoint", str(ckpts[1]), "--out", str(out)],
                       cwd=ROOT, capture_output=True, text=True, timeout=300, check=False)
    assert r.returncode == 0, r.stderr[-2000:]
    img = cv2.imread(str(out))
    assert img.shape[:2] == (2 * 2 * 48, 2 * 2 * 48)  # two rows of two 48-px frames, scaled 2x
    assert r.stdout.count("correct of") == 2 and not list(out.parent.glob("*.tmp.png"))


def test_contrafeat_eval_reports_each_checkpoint_and_residual(plane_dataset, tmp_path):
    """benchmarks/studies/contrafeat_eval.py: one section per (checkpoint, kpf residual) with the paper's
    table and the wrong-match split; the kpf threshold changes only the +kpf columns."""
    import torch

    from benchmarks.common.contrafeat import SMALL_MODEL
    from benchmarks.studies import contrafeat_eval
    from c3f_models.contrafeat.module import ContraFeat

    torch.manual_seed(0)
    ckpt = tmp_path / "m.ckpt"
    torch.save({"state_dict": ContraFeat(**SMALL_MODEL).state_dict(), "global_step": 7}, ckpt)
    out = tmp_path / "r" / "eval.md"
    contrafeat_eval.main(["--data", str(plane_dataset), "--seqs", "plane0", "plane1", "--checkpoint", str(ckpt),
                          "--max-residual-mm", "1.0", "0.05", "--size", "48", "--eval-gaps", "1",
                          "--eval-stride", "1", "--threads", "1", "--out", str(out)])
    text = out.read_text()
    assert text.count("(7 steps), kpf residual") == 2 and not list(out.parent.glob("*.tmp"))
    averages = [ln for ln in text.splitlines() if ln.startswith("| **average**")]
    assert len(averages) == 2
    cells = [[c.strip(" *") for c in ln.split("|")[2:6]] for ln in averages]  # SIFT, SIFT+kpf, CDF, CDF+kpf
    assert cells[0][0] == cells[1][0] and cells[0][2] == cells[1][2]  # no kpf: the threshold plays no part
    assert all("/" in c for c in cells[0])
    assert text.count("| SIFT+kpf |") == 2  # the wrong-match split, once per section

    bad = tmp_path / "bad.ckpt"
    torch.save({"weights": 1}, bad)
    with pytest.raises(SystemExit, match="bad.ckpt holds no state_dict"):
        contrafeat_eval.main(["--data", str(plane_dataset), "--checkpoint", str(bad), "--out", str(out)])
    assert out.read_text() == text  # the earlier report is intact


def _import_benchmark(name: str):
    return importlib.import_module(f"benchmarks.studies.{name}")


def test_ttt_schedule_keeps_the_papers_fractions():
    ttt = _import_benchmark("depthnet_ttt")
    assert ttt.scaled_milestones(200) == [80, 120, 170]
    assert ttt.scaled_milestones(10) == [4, 6, 8]
    assert ttt.scaled_milestones(1) == [1, 2, 3]  # distinct even when the schedule is tiny


@pytest.mark.slow
def test_ttt_benchmark_end_to_end(tmp_path, monkeypatch):
    """benchmarks/studies/depthnet_ttt.py on a tiny sequence: both tables, with the seven metrics twice."""
    from c3f_models.cli import main as cli
    from datamodules.synthetic.fixture import make_tiny_sequence

    monkeypatch.chdir(ROOT)
    data = tmp_path / "data"
    make_tiny_sequence(data / "train0", frames=8, size=48, seed=1)
    held_out = make_tiny_sequence(tmp_path / "held" / "test0", frames=8, size=48, seed=2)
    cli(["fit", "--config", "configs/trainer/cpu_smoke.yaml", "--config", "configs/depthnet/small.yaml",
         "--data.data_dir", str(data), "--data.frames.size", "[48, 48]", "--data.loader.batch_size", "2",
         "--data.split.val", "[]", "--data.split.test", "[]", "--data.split.train", '["train0"]',
         "--trainer.max_steps", "2",
         "--trainer.default_root_dir", str(tmp_path / "base"), "--trainer.logger.init_args.save_dir",
         str(tmp_path / "base"), "--trainer.enable_progress_bar", "false"])
    run = tmp_path / "base" / "tb" / "version_0"
    out = tmp_path / "ttt.md"
    monkeypatch.setattr(sys, "argv", ["depthnet_ttt.py", "--base-config", str(run / "config.yaml"), "--base-ckpt",
                                      str(run / "checkpoints" / "last.ckpt"), "--sequence", str(held_out),
                                      "--epochs", "1", "--size", "48", "--work", str(tmp_path / "w"),
                                      "--out", str(out)])
    _import_benchmark("depthnet_ttt").main()
    text = out.read_text()
    assert text.count("| base (before TTT) |") == 2 and text.count("| after TTT") == 2


def test_report_rewrites_only_its_generated_section(tmp_path):
    """benchmarks.common.report: the command line as typed from the repository root, the date,
    and a generated section that a rerun replaces while findings written by hand stay."""
    report = Report(str(ROOT / "benchmarks" / "protocols" / "slam_ate.py"), "Title", ["--set", "presets=seq1",
                                                                                       "--report", "a b"])
    assert report.command == "python -m benchmarks.protocols.slam_ate --set presets=seq1 --report 'a b'"
    first = report.render(["| table | 1 |"])
    assert first.startswith("# Title\n\nCommand: `python -m benchmarks.protocols.slam_ate --set presets=seq1 "
                            "--report 'a b'`"
                            "\n\nDate: ")
    out = tmp_path / "r.md"
    report.write(out, first)
    out.write_text("Findings above, by hand.\n\n" + out.read_text() + "\nFindings below.\n")
    report.write(out, report.render(["| table | 2 |"]))
    text = out.read_text()
    assert text.startswith("Findings above, by hand.\n\n<!-- generated by python -m benchmarks.protocols.slam_ate")
    assert "| table | 2 |" in text and "| table | 1 |" not in text and text.endswith(f"{END}\n\nFindings below.\n")

    plain = tmp_path / "plain.md"  # a file without a generated section gets one appended
    plain.write_text("Notes.\n")
    report.write(plain, first)
    assert plain.read_text().startswith("Notes.\n\n<!-- generated by") and plain.read_text().count(END) == 1
    plain.write_text(plain.read_text() * 2)
    with pytest.raises(SystemExit, match="plain.md: holds 2 generated report sections"):
        report.write(plain, first)


def test_publish_writes_the_same_numbers_as_json_beside_the_markdown(tmp_path):
    """Report.publish: the Markdown report and, beside it, its title, command, date, settings
    (paths in the repository relative to it), every table (numbers as numbers, the heading above
    it) and the protocol's own data."""
    import argparse
    import json

    report = Report(str(ROOT / "benchmarks" / "protocols" / "zoo.py"), "Zoo", ["--only", "depth"])
    body = ["Set-up.", "", "| case | ATE cm | share % | note |", "|---|---|---|---|",
            "| seq1 | 0.36 | **100** | a \\| b |", "| seq3 | - | 1e-3 | `x` |", "", "## Per stage", "",
            "| stage | ms |\n|---|---|\n| io | 2 |"]  # a table inside one line, as some reports build them
    settings = argparse.Namespace(work=ROOT / "runs" / "bench" / "zoo", report=tmp_path / "zoo.md", sizes=(64, 128))
    text = report.publish(tmp_path / "r" / "zoo.md", body, settings, data={"sections": {"depth": {"abs_rel": 0.1}}})
    assert (tmp_path / "r" / "zoo.md").read_text().count("| seq1 | 0.36 | **100** |") == 1 and "| io | 2 |" in text
    record = json.loads((tmp_path / "r" / "zoo.json").read_text())
    assert record["module"] == "benchmarks.protocols.zoo" and record["title"] == "Zoo"
    assert record["command"] == "python -m benchmarks.protocols.zoo --only depth" and f"Date: {record['date']}" in text
    assert record["settings"] == {"work": "runs/bench/zoo", "report": str(tmp_path / "zoo.md"), "sizes": [64, 128]}
    assert record["tables"] == [
        {"section": None, "columns": ["case", "ATE cm", "share %", "note"],
         "rows": [["seq1", 0.36, 100, "a | b"], ["seq3", "-", 0.001, "`x`"]]},
        {"section": "Per stage", "columns": ["stage", "ms"], "rows": [["io", 2]]}]
    assert record["data"] == {"sections": {"depth": {"abs_rel": 0.1}}}
    assert sorted(p.name for p in (tmp_path / "r").iterdir()) == ["zoo.json", "zoo.md"]  # nothing half-written


def test_fallback_pairs_compares_plain_guided_and_dense(tmp_path):
    """benchmarks/studies/slam_fallback_pairs.py's pair table on a tiny 128 px sequence (every pair tried):
    plain matching links every pair of the slow insertion, guided matching from the last
    motion finds matches too, the dense odometry's verdict is one of the fallback's outcomes,
    and the errors are against the true motion."""
    import numpy as np

    from benchmarks.studies.slam_fallback_pairs import pair_rows, summary_line
    from c3f_slam.io import Sequence
    from datamodules.synthetic.fixture import make_tiny_sequence

    rows = pair_rows(Sequence(make_tiny_sequence(tmp_path / "seq", frames=8, size=128, seed=3)), step=1)
    assert len(rows) == 7 and not any(r["plain_failed"] for r in rows)
    assert all(r["guided"][0] >= 10 for r in rows), [r["guided"] for r in rows]
    assert {r["dense"][0] for r in rows} <= {"accepted", "no_convergence", "implausible_motion", "low_overlap",
                                             "photometric_residual"}
    motion = np.array([r["motion"][0] for r in rows])
    assert (motion > 1.0).all() and (np.array([r["plain"][1] for r in rows]) < 0.5 * motion).all()
    assert summary_line("tiny", rows).startswith("| tiny | 7 | 0 | 0 |")


def test_trajectory_identity_sets_and_comparison(tmp_path):
    """benchmarks/protocols/trajectory_identity.py: its sets are the benchmarks' sequences, run as each
    benchmark runs them (tracking without a mesh, coverage with one); two runs that write the
    same trajectory are identical, a different one is not, and a run of the same code key is
    reused instead of run again."""
    from benchmarks.protocols import trajectory_identity as ti

    sets = {s: ti.targets([s]) for s in ("coverage", "tracking128", "tracking256", "smoke")}
    assert [len(v) for v in sets.values()] == [7, 12, 12, 1]
    assert {t.spec.frames for t in sets["tracking128"]} == {600} and {t.spec.size for t in sets["coverage"]} == {128}
    assert "fusion.enabled=false" in sets["tracking256"][0].command(Path("s"), Path("o"))
    assert "fusion.enabled=false" not in sets["coverage"][0].command(Path("s"), Path("o"))
    assert len(ti.targets(["coverage", "smoke"])) == 7

    seq = tmp_path / "seq"
    seq.mkdir()
    (seq / "camera.json").write_text("{}")  # an existing sequence: not generated again
    write = ("import json, pathlib, sys; o = pathlib.Path(sys.argv[1]); o.mkdir(parents=True, exist_ok=True); "
             "(o / 'trajectory.txt').write_text(sys.argv[2]); "
             "(o / 'summary.json').write_text(json.dumps({'status': 'ok', 'frames': 3, 'registered_share': 1.0}))")

    def target(text: str) -> ti.Target:
        return ti.Target("seq", "test", ti.SimSequence("seq1", 1, 3, 64), lambda s, o: [sys.executable, "-c", write,
                                                                                         str(o), text])

    r = ti.run_side(target("0 0 0\n"), seq, ROOT, "key1", tmp_path / "a")
    assert r["status"] == "ok" and r["frames"] == 3 and not r["reused"] and r["mesh_sha256"] is None
    again = ti.run_side(target("1 1 1\n"), seq, ROOT, "key1", tmp_path / "a")
    assert again["reused"] and again["sha256"] == r["sha256"]  # same code: the run is not repeated
    other = ti.run_side(target("1 1 1\n"), seq, ROOT, None, tmp_path / "a")
    assert not other["reused"] and other["sha256"] != r["sha256"]
    lines = ti.table([{"name": "seq", "group": "test", "identical": False, "mesh_identical": None,
                       "before": r, "after": other}])
    assert "| seq | test | 3 | 100.0 / 100.0 | **no** |" in lines[-1]


def test_trajectory_identity_mesh_fingerprint_ignores_triangle_order(tmp_path):
    """The same triangles listed in another order (and turned, winding kept) give the same
    fingerprint; a moved vertex or a flipped triangle does not."""
    import numpy as np
    import open3d as o3d

    from benchmarks.protocols.trajectory_identity import mesh_fingerprint

    rng = np.random.default_rng(0)
    v, t = rng.random((30, 3)), rng.permutation(30)[:27].reshape(9, 3)
    c = rng.random((30, 3))

    def write(name: str, verts: np.ndarray, tris: np.ndarray, perm: np.ndarray | None = None) -> Path:
        perm = np.arange(len(verts)) if perm is None else perm  # vertex k of the new mesh is verts[perm[k]]
        inv = np.argsort(perm)
        mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(verts[perm]), o3d.utility.Vector3iVector(inv[tris]))
        mesh.vertex_colors = o3d.utility.Vector3dVector(c[perm])
        o3d.io.write_triangle_mesh(str(tmp_path / name), mesh)
        return tmp_path / name

    ref = mesh_fingerprint(write("a.ply", v, t))
    shuffled = np.roll(t[rng.permutation(len(t))], 1, axis=1)  # other order, each triangle turned
    assert mesh_fingerprint(write("b.ply", v, shuffled, rng.permutation(30))) == ref
    moved = v.copy()
    moved[t[0, 0]] += 1e-12
    assert mesh_fingerprint(write("c.ply", moved, t)) != ref
    assert mesh_fingerprint(write("d.ply", v, t[:, ::-1])) != ref  # the winding counts
    assert mesh_fingerprint(tmp_path / "none.ply") is None


def test_zoo_ablation_runs_in_chunks(tmp_path, monkeypatch):
    """The zoo protocol's ablation fits continue after an interruption: a finished fit with the
    same settings is read back (nothing runs), an interrupted one resumes from its last
    checkpoint, and one made with other settings is started again from an empty folder."""
    import json

    import c3f_models.zoo.evaluate as evaluate
    from benchmarks.protocols import zoo

    calls: list[list[str]] = []
    monkeypatch.setattr(zoo, "_cli", lambda args, what, ok=(0,): calls.append(args))
    monkeypatch.setattr(evaluate, "depth_heldout", lambda path, seqs: {"mean": {"sq_rel": 0.5}})
    run, settings = tmp_path / "c3fusion_s1", {"seed_everything": 1, "trainer": {"max_steps": 3}}
    assert zoo._ablation_run(run, settings, ["a.yaml"], [], "x") == {"sq_rel": 0.5}
    assert "--ckpt_path" not in calls[0] and calls[1][2] == "export"
    calls.clear()
    assert zoo._ablation_run(run, settings, ["a.yaml"], [], "x") == {"sq_rel": 0.5} and not calls  # read back
    (run / "result.json").unlink()  # interrupted after its checkpoint
    ckpt = run / "tb" / "version_0" / "checkpoints" / "last.ckpt"
    ckpt.parent.mkdir(parents=True)
    ckpt.write_bytes(b"")
    zoo._ablation_run(run, settings, ["a.yaml"], [], "x")
    assert calls[0][-2:] == ["--ckpt_path", str(ckpt)]
    calls.clear()
    other = {"seed_everything": 1, "trainer": {"max_steps": 5}}
    zoo._ablation_run(run, other, ["a.yaml"], [], "x")
    assert "--ckpt_path" not in calls[0] and not ckpt.exists()
    assert json.loads((run / "result.json").read_text())["settings"] == other
    calls.clear()
    zoo._ablation_run(run, other, ["a.yaml"], [], "x", start_sha256="abc")  # the same settings from another start
    assert calls and "--ckpt_path" not in calls[0]


def test_zoo_ablation_from_a_self_supervised_start(tmp_path, monkeypatch):
    """The self-supervised start is fit from random weights with the Monodepth2 objective; both
    objectives then start from its checkpoint, and a changed start (another hash) is not read
    back from a finished pair."""
    from benchmarks.protocols import zoo
    from c3f_slam.models.zoo import sha256_of

    fits: list[tuple] = []

    def fake_run(run, last, configs, seqs, what, start_sha256=None):
        fits.append((run.name, last["model"]["init_args"]["init_weights"], [str(c) for c in configs], start_sha256,
                     last["trainer"]["max_steps"]))
        ckpt = run / "tb" / "version_0" / "checkpoints" / "last.ckpt"
        ckpt.parent.mkdir(parents=True, exist_ok=True)
        if run.name == "start":
            ckpt.write_bytes(b"weights")
        return {"sq_rel": 0.5}

    monkeypatch.setattr(zoo, "_ablation_run", fake_run)
    monkeypatch.setattr(zoo, "simulate", lambda presets, size, folder: [folder / "seq1_s1", folder / "seq1_s2"])
    a = argparse.Namespace(depth="zoo:c3f-depth-r18w32", work=tmp_path, quick=True, ablation_steps=3,
                           ablation_seeds=[1, 2], start_steps=5)
    out = zoo.ablation_selfsup_section(a, [])
    start, *pairs = fits
    assert start[0] == "start" and start[1] is None and start[2][-1] == zoo.ABLATION["monodepth2"] and start[4] == 5
    ckpt = str(tmp_path / "ablation_selfsup" / "start" / "tb" / "version_0" / "checkpoints" / "last.ckpt")
    assert len(pairs) == 4 and all(p[1] == ckpt and p[3] == sha256_of(Path(ckpt)) and p[4] == 3 for p in pairs)
    assert {p[2][-1] for p in pairs} == set(zoo.ABLATION.values())
    assert out["start"] == {"sq_rel": 0.5} and out["start_steps"] == 5 and set(out["c3fusion"]) == {"1", "2"}
    assert any("self-supervised start" in line for line in zoo.ablation_selfsup_lines(out))


def test_zoo_slam_settings_reach_every_run_and_the_cache(tmp_path, monkeypatch):
    """The setting ``slam_set`` goes to every SLAM run of the slam and coverage sections, is kept with the
    section, shown in its Markdown, and a section kept with other settings is computed again."""
    from benchmarks.protocols import zoo

    commands: list[list[str]] = []
    monkeypatch.setattr(zoo, "_slam_one", lambda seq, out, options: commands.append(options) or {
        "status": "ok", "registered_share": 1.0, "ate_cm": 0.1, "path_cm": 10.0, "ate_share_of_path": 0.01,
        "sim3_scale": 1.0})
    a = argparse.Namespace(depth="zoo:d", features="zoo:f", slam_set=["match_filter.reprojection_refit=true"],
                           work=tmp_path)
    seqs = [Path("seq1_s2001")]
    s = zoo._cached(tmp_path, "slam", False, lambda: zoo.slam_section(a, seqs), a.slam_set)
    assert all(c[-2:] == ["--set", "match_filter.reprojection_refit=true"] for c in commands) and len(commands) == 2
    assert s["settings"] == a.slam_set and set(s) == {"contrafeat", "sift", "settings", "wall_s"}
    text = "\n".join(zoo.slam_lines(s))
    assert "`--set match_filter.reprojection_refit=true`" in text and text.count("| seq1_s2001 |") == 2
    commands.clear()
    assert zoo._cached(tmp_path, "slam", False, lambda: zoo.slam_section(a, seqs), a.slam_set) == s
    assert not commands  # same settings: read back
    a.slam_set = []
    again = zoo._cached(tmp_path, "slam", False, lambda: zoo.slam_section(a, seqs), a.slam_set)
    assert len(commands) == 2 and again["settings"] == [] and "Not the defaults" not in "\n".join(zoo.slam_lines(again))
    from benchmarks.protocols.coverage_accuracy import slam_command

    assert slam_command(Path("s"), Path("o"), None, ("--set", "k=v"))[-2:] == ["--set", "k=v"]


def test_depth_edges_measures_a_step_and_its_blur():
    """benchmarks/studies/depth_edges.py: a fold crest in front of the wall (a 50 % depth step)
    is found; the truth keeps all of it, a prediction blurred over 16 px keeps little."""
    import numpy as np

    edges = _import_benchmark("depth_edges")
    true = np.full((48, 48), 0.03)
    true[:, 24:] = 0.045  # log step 0.405
    ramp = np.interp(np.arange(48), [16, 32], [np.log(0.03), np.log(0.045)])
    blurred = np.exp(np.tile(ramp, (48, 1)))
    same = edges.edge_measures(true, true, 0.25)
    assert same["true_step"] == pytest.approx(np.log(1.5)) and same["kept"] == 1.0 and same["range"] == 1.0
    soft = edges.edge_measures(true, blurred, 0.25)
    assert soft["pred_step"] < 0.15 and soft["kept"] == 0.0 and soft["pixels"] == same["pixels"]
    assert edges.edge_measures(np.full((48, 48), 0.03), true, 0.25) is None  # no true edge


def test_depth_scale_wobble_finds_a_scale_that_moves_more_than_the_camera():
    """benchmarks/studies/depth_scale_wobble.py: a prediction with the true scale has no wobble;
    one whose scale alternates by 2 % at 2 cm depth while the camera moves 0.2 mm per frame
    wobbles twice as far as the camera moves."""
    import numpy as np

    wobble = _import_benchmark("depth_scale_wobble")
    true = np.full((8, 8), 0.02)
    assert wobble.frame_scale(true, true) == (1.0, 0.02)
    assert wobble.frame_scale(true, 0.5 * true)[0] == pytest.approx(2.0)
    assert np.isnan(wobble.frame_scale(np.zeros((8, 8)), true)[0])
    positions = np.stack([np.zeros(20), np.zeros(20), 0.0002 * np.arange(20)], axis=1)
    steady = wobble.wobble_measures(np.ones(20), np.full(20, 0.02), positions, lag=2)
    assert steady["std"] == 0.0 and steady["change_median"] == 0.0 and steady["wobble_over_motion"] == 0.0
    k = np.where(np.arange(20) % 2 == 0, 1.0, 1.02)
    shaky = wobble.wobble_measures(k, np.full(20, 0.02), positions, lag=2)
    assert shaky["change_median"] == pytest.approx(0.02, rel=0.02)
    assert shaky["wobble_over_motion"] == pytest.approx(2.0, rel=0.02) and shaky["lag_corr"] == pytest.approx(1.0)
    assert shaky["wobble_over_motion_lag"] == 0.0  # two frames on, the same scale again
