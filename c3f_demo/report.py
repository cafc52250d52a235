"""The demo's ``report`` stage: figures into ``DIR/figures`` and ``DIR/report.html``.

:func:`build_report` writes the HTML from plain inputs (the metrics JSON, the stage table, the
figure files under the demo folder), so it is tested on tiny fake inputs; :class:`Report` makes
the figures and gathers those inputs. Lengths are metres in the data, cm or mm on the page.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from c3f_demo import html as H
from c3f_models.zoo.card import summary_numbers
from c3f_slam.view.page import layer_table_rows, view_fragment, view_scripts

#: section ids of the report, in order (the tests check every one is present)
SECTIONS = ("summary", "models", "deviations", "depth", "matches", "trajectories", "meshes", "view3d",
            "keyframe-graph", "unseen", "timings", "environment", "artefacts")
VIDEO_EMBED_MAX = 8_000_000  #: bytes: a larger video is linked beside the report, not embedded
METRIC_LABELS = {"abs_rel": "Abs Rel", "sq_rel": "Sq Rel (cm)", "rmse": "RMSE (cm)", "rmse_log": "RMSE log",
                 "a1": "δ < 1.25", "a2": "δ < 1.25²", "a3": "δ < 1.25³"}
ARTEFACTS = [
    ("data/train/*, data/test/heldout", "simulator sequences: rgb/, depth/, poses.txt (TUM), camera.json, mesh.ply",
     "any image viewer; MeshLab / Open3D for mesh.ply"),
    ("runs/depthnet, runs/depthnet_ttt, runs/contrafeat", "training runs (pre-training, test-time training on the "
     "held-out sequence, descriptors): TensorBoard events, config.yaml, checkpoints/last.ckpt",
     "tensorboard --logdir DIR/runs"),
    ("models/*/*.onnx, export.json", "ONNX exports with metadata and parity (models/depthnet: the network SLAM "
     "used; models/depthnet_pretrained: before test-time training)", "python -m c3f_slam inspect FILE"),
    ("slam/NAME/trajectory.txt", "estimated camera-to-world trajectory (TUM)", "evo (evo_traj tum ...)"),
    ("slam/NAME/mesh.ply, coverage.ply", "reconstruction; ground-truth surface painted seen / unseen",
     "MeshLab / Open3D"),
    ("slam/NAME/coverage.json, coverage_map.png, unseen.ply", "the run's own unseen-wall estimate (no ground truth); "
     "coverage_map_truth.png: the truth's map for the same run", "any text editor / image viewer; MeshLab"),
    ("slam/NAME/summary.json, evaluation.json, keyframe_graph.json", "run and evaluation numbers", "any text editor"),
    ("slam/NAME/view.html, rerender.mp4, flythrough.mp4", "the 3D view of one configuration at the full page "
     "budget, the input beside the re-rendered reconstruction, the fly-through (python -m c3f_slam view)",
     "any browser (offline)"),
    ("metrics/*.json, figures/*.png", "the report's numbers and images", "any text editor / image viewer"),
    ("logs/*.log", "the output of every command the demo ran", "any text editor"),
]


def _num(x, scale: float = 1.0, digits: int = 3) -> str:
    try:
        v = float(x) * scale
    except (TypeError, ValueError):
        return "n/a"
    return f"{v:.{digits}f}" if math.isfinite(v) else "n/a"


def _summary(d: dict) -> str:
    rows = []
    for name, r in d["metrics"]["slam"].items():
        if r.get("status") == "ok":
            rows.append([H.esc(r.get("title", name)), "ok", _num(r["ate_sim3_m"], 100, 2),
                         _num(r["gt_length_m"], 100, 1), _num(r["registered_share"], 100, 1)])
        else:
            rows.append([H.esc(r.get("title", name)), '<span class="fail">FAILED</span>',
                         f'<span class="fail">{H.esc(r.get("error", "failed"))}</span>', "", ""])
    mode = "quick" if d["config"].get("quick") else "default"
    ttt = ("test-time trained DepthNet on the held-out sequence (self-supervised), "
           if d["config"].get("ttt", {}).get("steps") else "")
    start = ("started from the zoo's DepthNet and ContraFeat (see Models)" if d.get("zoo")
             else "trained DepthNet and ContraFeat on CPU")
    return (f"<p>Simulated colon, {start}, {ttt}exported to ONNX, reconstructed "
            f"the held-out sequence in {len(rows)} configurations ({mode} preset). ATE is the RMSE after Sim(3) "
            "alignment, on the registered frames.</p>"
            + H.table(["configuration", "status", "ATE (cm)", "path length (cm)", "registered (%)"], rows))


def _models(d: dict) -> str:
    """Which networks ran: the zoo entries with their cards' held-out numbers, or the demo's own training."""
    zoo = d.get("zoo") or {}
    if not zoo:
        return ("<p>Both networks were trained by this demo (<code>--from-scratch</code>): see Deviations for "
                "their size and budget.</p>")
    rows = []
    for note in zoo.values():
        nums = H.esc(summary_numbers(note.get("metrics", {})))
        t = note.get("training", {})
        rows.append([f"<code>zoo:{H.esc(note['zoo'])}</code>", H.esc(note.get("kind", "")),
                     H.esc(note.get("summary", "")),
                     f"{t.get('steps', 'n/a')} steps, {_num(t.get('wall_s'), 1 / 60, 0)} min", nums])
    guard = d.get("ttt_guard")
    said = ""
    if guard:
        events = ", ".join(e["event"] + (f" at step {e['step']}" if "step" in e else "") for e in guard["events"])
        said = (f"<p>Test-time training guard: best weights (lowest photometric term, no ground truth) from step "
                f"{guard.get('best_step')}; events: {H.esc(events or 'none (no collapse)')}.</p>")
    return ("<p>The models this demo started from, with the held-out numbers of their model cards "
            "(<code>zoo/NAME/README.md</code>; simulator sequences this demo did not use). This run's own numbers "
            "are in the sections below.</p>"
            + H.table(["model", "kind", "what", "training", "card's held-out numbers"], rows) + said)


def _deviations(d: dict) -> str:
    dep = d["config"]["depth"]
    items = []
    if d.get("zoo"):
        items.append("The networks come from the project's zoo: trained on the simulator with a supervised depth term "
                     "and at CPU size; each card lists its deviations from the paper (<code>zoo/NAME/README.md"
                     "</code>).")
        ttt = d["config"].get("ttt", {})
        if ttt.get("steps"):
            items.append(f"DepthNet was <b>test-time trained on the held-out sequence</b> from the zoo weights with "
                         f"the paper's objective (<code>configs/depthnet/paper_objective.yaml</code>, no ground "
                         f"truth; {ttt['steps']} steps, lr {ttt['lr']:g}; the paper's schedule is 200 epochs) under "
                         "the test-time training guard (stop and roll back if the depth goes flat; keep the weights "
                         "with the lowest photometric term). The paper's configuration uses that network, the "
                         "configuration \"without TTT\" the zoo's.")
        return '<div class="note"><ul>' + "".join(f"<li>{i}</li>" for i in items) + "</ul></div>"
    if dep["lambda_gt_depth"] > 0:
        items.append(f"DepthNet was trained <b>with a supervised depth term</b> on the simulator's true depth "
                     f"(<code>model.loss.lambda_gt_depth {dep['lambda_gt_depth']}</code>); the paper's objective is "
                     "self-supervised only. It is off by default in the paper configs.")
    if not dep["paper_extras"]:
        items.append("The paper's extra depth terms (L_ph-extra, L_dc, outlier and specular masks) were off "
                     "(<code>configs/depthnet/monodepth2.yaml</code>) to fit the CPU budget.")
    ttt = d["config"].get("ttt", {})
    if ttt.get("steps"):
        items.append(f"After that pre-training, DepthNet was <b>test-time trained on the held-out sequence</b>, "
                     f"self-supervised as in the paper (no ground truth; {ttt['steps']} steps, lr {ttt['lr']:g}, "
                     "<code>configs/depthnet/ttt.yaml</code>); the paper's configuration and the odometry use that "
                     "network, the configuration \"without TTT\" the pre-trained one. The paper's schedule is 200 "
                     "epochs.")
    else:
        items.append("No test-time training on the held-out sequence: predicted depth comes from the pre-trained "
                     "network.")
    items.append(f"Networks at CPU size (DepthNet {dep['size']} px, {dep['steps']} steps; ContraFeat "
                 f"{d['config']['features']['size']} px, {d['config']['features']['steps']} steps), far from the "
                 "paper's training.")
    return '<div class="note"><ul>' + "".join(f"<li>{i}</li>" for i in items) + "</ul></div>"


def _depth(d: dict, root: Path) -> str:
    m = d["metrics"]["depth"]
    before = m.get("before_ttt")
    scale = {"sq_rel": 100, "rmse": 100}
    cell = lambda group, k: _num(group[k], scale.get(k, 1))  # noqa: E731
    if before:
        head = ["metric", "before TTT, median scaling", "after TTT, median scaling", "before TTT, metric",
                "after TTT, metric"]
        rows = [[label, cell(before["median_scaled"], k), cell(m["median_scaled"], k), cell(before["metric"], k),
                 cell(m["metric"], k)] for k, label in METRIC_LABELS.items()]
        b, a = before["median_scaled"]["abs_rel"], m["median_scaled"]["abs_rel"]
        verdict = ("left the error unchanged (within 1 %)" if abs(a - b) <= 0.01 * b else
                   "lowered the error" if a < b else "raised the error")
        which = ("the exported DepthNet before and after test-time training (TTT) on this sequence (the paper's "
                 "configuration uses the one after). <b>Test-time training " + verdict + "</b>: Abs Rel "
                 f"{_num(b)} -> {_num(a)} (median scaling)")
    else:
        head = ["metric", "per-image median scaling", "metric (no scaling)"]
        rows = [[label, cell(m["median_scaled"], k), cell(m["metric"], k)] for k, label in METRIC_LABELS.items()]
        which = "the exported DepthNet"
    fig = d["figures"].get("depth", {})
    rng = fig.get("range_m", [0, 0])
    scales = ", ".join(f"{H.esc(k)} x {_num(v, 1, 2)}" for k, v in fig.get("scales", {}).items())
    return (H.image(root / "figures" / "depth_samples.png",
                    f"held-out frames | predicted depth ({scales}: the metric scale each export recorded, as SLAM "
                    f"uses it) | true depth; colour {_num(rng[0], 100, 1)}-{_num(rng[1], 100, 1)} cm, "
                    "black = no depth")
            + f"<p>Seven depth metrics of {which}. {len(m['frames'])} held-out frames "
              f"(median scale true/predicted: {_num(m['median_scaled'].get('scale'), 1, 3)}). Metric: depth times "
              "the scale the export measured on the training sequences.</p>"
            + H.table(head, rows))


def _matches(d: dict, root: Path) -> str:
    m = d["metrics"]["matches"]
    rows = [[name, m[key]["found"], m[key]["correct"], _num(m[key]["precision"], 100, 1),
             _num(m[key]["recall"], 100, 1)] for key, name in (("sift", "SIFT"), ("contrafeat", "ContraFeat"))]
    i, j = m["pair"]
    return (f"<p>Frames {i} and {j} of the held-out sequence, {m['keypoints']} SIFT keypoints, "
            f"{m['ground_truth']} ground-truth matches. Green = correct (within 2 px), yellow = near miss, "
            "red = wrong. Top row SIFT, bottom row ContraFeat.</p>"
            + H.table(["descriptor", "matches", "correct", "precision (%)", "recall (%)"], rows)
            + H.image(root / m["figure"], "SIFT (top) vs ContraFeat (bottom)"))


def _per_run(d: dict, root: Path, file: str, caption, absent: dict[str, str] | None = None) -> str:
    """One image per configuration (``slam/NAME/FILE``); ``absent``: name -> what to say instead
    when a configuration writes no such file by design."""
    out = []
    for name, r in d["metrics"]["slam"].items():
        title = H.esc(r.get("title", name))
        if r.get("status") != "ok":
            out.append(f'<p class="fail">{title}: failed, nothing to show ({H.esc(r.get("error", ""))})</p>')
        elif name in (absent or {}) and not (root / "slam" / name / file).is_file():
            out.append(f"<h3>{title}</h3><p>{H.esc(absent[name])}</p>")
        else:
            out.append(f"<h3>{title}</h3>" + H.image(root / "slam" / name / file, caption(r)))
    return "".join(out)


def _meshes(d: dict, root: Path) -> str:
    out = ["<p>TSDF meshes, offscreen renders (vertex colours, light at the eye).</p>"]
    for name, r in d["metrics"]["slam"].items():
        files = d["figures"].get("meshes", {}).get(name, [])
        if r.get("status") != "ok" or not files:
            out.append(f'<p class="fail">{H.esc(r.get("title", name))}: no mesh to show</p>')
            continue
        out.append(f"<h3>{H.esc(r.get('title', name))}</h3>" + "".join(
            H.image(root / "figures" / f, f.rsplit("_", 1)[-1][:-4], 300) for f in files))
    return "".join(out)


def _view3d(d: dict, root: Path) -> str:
    """The interactive 3D view of one configuration and its two videos (``d["view"]``)."""
    v = d.get("view")
    if not v:
        return '<p class="fail">No configuration gave a reconstruction to view.</p>'
    title = H.esc(v["title"])
    if v.get("error"):
        return f'<p class="fail">{title}: no 3D view ({H.esc(v["error"])})</p>'
    cost = "; ".join(f"{H.esc(name)} {_num(ms, 1, 0)} ms per rendered frame" for name, ms in v["render_ms"].items())
    return (f"<p>{title}, in 3D: drag to orbit, right drag to pan, wheel to zoom; switch the layers on the right. "
            f"The geometry is decimated to the report's budget ({v['budget_triangles']:,} triangles); "
            f"<code>slam/{H.esc(v['run'])}/view.html</code> has it at the full page budget, linked to the PLY "
            "files.</p>" + view_fragment(v["data"]) + H.table(["layer", "data"], layer_table_rows(v["data"]))
            + "<p>The input beside the reconstruction rendered from each frame's estimated pose (same intrinsics; "
              "unseen wall blue), and a fly-through of the final model along the smoothed camera path, rendered "
              f"on the CPU ({cost}).</p>"
            + "".join(H.video(root, path, caption, VIDEO_EMBED_MAX) for path, caption in v["videos"]))


def _unseen(d: dict, root: Path) -> str:
    u = d["figures"].get("unseen", {})
    if u.get("source") == "run":
        out = ["<p>Share of the colon wall each run estimated it did not see, from its own trajectory and depth "
               "(<code>coverage.json</code>, no ground truth), beside the truth <code>c3f_slam evaluate</code> "
               "measured for the same run. Maps: the wall unrolled along the explored centreline (cm), unseen in "
               "blue, seen in the wall's colour (grey: seen but no colour); the true map of the same run below its "
               "estimate.</p>"]
        for r in u["runs"]:
            title = H.esc(r["run"])
            if r.get("status") != "ok":
                out.append(f'<p class="fail">{title}: no estimate ({H.esc(r.get("reason") or r.get("status"))})</p>')
                continue
            truth = r.get("truth") or {}
            vs = (f" (truth {_num(truth.get('unseen_share'), 100, 1)} %, error {_num(truth.get('error_pp'), 1, 1)} pp)"
                  if truth else " (no truth measured)")
            segs = [[_num(s["start_m"], 100, 1), _num(s["end_m"], 100, 1), _num(s["unseen_share"], 100, 1)]
                    for s in r.get("segments", [])]
            truth_map = H.image(root / r["truth_map"], "true coverage map", 520) if r.get("truth_map") else ""
            out.append(f"<h3>{title}: <b>{_num(r['unseen_share'], 100, 1)} %</b> unseen{vs}</h3>"
                       + H.image(root / r["map"], "estimated coverage map", 520) + truth_map
                       + H.table(["from (cm)", "to (cm)", "unseen (%)"], segs))
        return "".join(out)
    if u.get("source") == "ground_truth":
        out = ["<p><b>Ground truth</b> (not estimated by the run): the simulator's true surface near the path, "
               "painted seen (green) / unseen (red) by each reconstruction after aligning it with the ATE's "
               "transform (<code>c3f_slam evaluate</code>).</p>"]
        for r in u["runs"]:
            out.append(f"<h3>{H.esc(r['run'])}: {_num(r['seen_share'], 100, 1)} % of the whole true mesh seen</h3>"
                       + "".join(H.image(root / "figures" / f, f.rsplit("_", 1)[-1][:-4], 300) for f in r["renders"]))
        return "".join(out)
    return '<p class="fail">No configuration gave a reconstruction to measure coverage with.</p>'


def _timings(d: dict) -> str:
    rows = [[name, _num(sec, 1, 1), H.esc(status)] for name, sec, status in d["timings"]]
    return H.table(["stage", "seconds", "status"], rows)


def _environment(d: dict) -> str:
    rows = [[H.esc(k), H.esc(v)] for k, v in d["environment"].items()]
    return H.table(["item", "value"], rows) + f"<p>Settings: <code>{H.esc(json.dumps(d['config']))}</code></p>"


def _artefacts() -> str:
    return H.table(["file (in the demo folder)", "what", "open with"],
                   [[f"<code>{H.esc(a)}</code>", H.esc(b), H.esc(c)] for a, b, c in ARTEFACTS])


def build_report(root: Path, d: dict) -> str:
    """HTML of the report. ``d``: ``config`` (DemoConfig.as_dict), ``metrics`` (slam, depth, matches:
    the evaluate stage's JSON), ``figures`` (depth, meshes, unseen), ``timings`` [(stage, s, status)],
    ``environment`` {name: value}, ``view`` (optional, :func:`c3f_demo.report_stage.view_entry`); image
    and video paths are relative to ``root``."""
    ate = lambda r: f"ATE {_num(r.get('ate_sim3_m'), 100, 2)} cm, path {_num(r.get('gt_length_m'), 100, 1)} cm"  # noqa: E731
    parts = {
        "summary": ("Summary", _summary(d)),
        "models": ("Models", _models(d)),
        "deviations": ("Deviations from the paper", _deviations(d)),
        "depth": ("Depth", _depth(d, root)),
        "matches": ("Matches: SIFT vs ContraFeat", _matches(d, root)),
        "trajectories": ("Trajectories vs ground truth", _per_run(d, root, "trajectory.png", ate)),
        "meshes": ("Reconstructed meshes", _meshes(d, root)),
        "view3d": ("3D view and videos", _view3d(d, root)),
        "keyframe-graph": ("Keyframe connectivity graph", _per_run(
            d, root, "keyframe_graph.png", lambda r: "",
            {"odometry": "No keyframe graph: frame-to-frame odometry chains each frame to the one before."})),
        "unseen": ("Unseen surface", _unseen(d, root)),
        "timings": ("Time per stage", _timings(d)),
        "environment": ("Versions, machine, seeds", _environment(d)),
        "artefacts": ("Files in this folder", _artefacts()),
    }
    tail = view_scripts() if (d.get("view") or {}).get("data") else ""
    return H.page("C3Fusion demo report", [H.section(sid, *parts[sid]) for sid in SECTIONS], tail)
