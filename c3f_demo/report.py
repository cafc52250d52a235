"""The report's third step: :func:`build_report` writes the HTML of ``DIR/report.html`` from the
collected data and the figures alone (:mod:`c3f_demo.report_records`), reading no file, so it is
tested on tiny fake inputs. Lengths are metres in the data, cm or mm on the page.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from c3f_demo import html as H
from c3f_demo.report_records import Figures, ReportData
from c3f_models.zoo.card import summary_numbers
from c3f_slam.view.page import layer_table_rows, view_fragment, view_scripts

#: section ids of the report, in order (the tests check every one is present)
SECTIONS = ("summary", "models", "deviations", "depth", "matches", "trajectories", "meshes", "view3d",
            "keyframe-graph", "unseen", "timings", "environment", "artefacts")
#: section ids of the report of a user's video (``--video``): no ground truth, so no depth metrics,
#: matches against true correspondences, ATE or true coverage
VIDEO_SECTIONS = ("summary", "input", "models", "tissue", "frames", "trajectories", "meshes", "view3d",
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
VIDEO_ARTEFACTS = [
    ("data/video", "the video's frames as a sequence: rgb/, camera.json, frames.csv (each frame's time in the "
     "video), ingest.json", "any image viewer / text editor"),
    ("runs/depthnet_ttt", "test-time training on the video's frames: TensorBoard events, config.yaml, "
     "checkpoints/last.ckpt, checkpoints/guard.json", "tensorboard --logdir DIR/runs"),
    ("models/*/*.onnx, export.json", "models/depthnet: the tuned DepthNet (the paper's configuration); "
     "models/depthnet_pretrained, models/contrafeat: the zoo's files", "python -m c3f_slam inspect FILE"),
    ("slam/NAME/trajectory.txt", "estimated camera-to-world trajectory (TUM; time = frame of data/video)",
     "evo (evo_traj tum ...)"),
    ("slam/NAME/mesh.ply, unseen.ply", "reconstruction; the same with the unseen wall added in blue",
     "MeshLab / Open3D"),
    ("slam/NAME/coverage.json, coverage_map.png", "the run's own unseen-wall estimate", "any text editor / image "
     "viewer"),
    ("slam/NAME/summary.json, tissue_mask.png, keyframe_graph.json", "run numbers (frames, skipped frames by cause, "
     "decisions, tissue area), the tissue mask, the keyframe graph", "any text editor / image viewer"),
    ("slam/NAME/view.html, rerender.mp4, flythrough.mp4", "the 3D view at the full page budget, the input beside "
     "the re-rendered reconstruction, the fly-through (python -m c3f_slam view)", "any browser (offline)"),
    ("metrics/slam.json, figures/*.png", "the report's numbers and images", "any text editor / image viewer"),
    ("logs/*.log", "the output of every command the run made", "any text editor"),
]


def _num(x, scale: float = 1.0, digits: int = 3) -> str:
    try:
        v = float(x) * scale
    except (TypeError, ValueError):
        return "n/a"
    return f"{v:.{digits}f}" if math.isfinite(v) else "n/a"


def _summary(d: ReportData) -> str:
    rows = []
    for name, r in d.metrics["slam"].items():
        if r.get("status") == "ok":
            rows.append([H.esc(r.get("title", name)), "ok", _num(r["ate_sim3_m"], 100, 2),
                         _num(r["gt_length_m"], 100, 1), _num(r["registered_share"], 100, 1)])
        else:
            rows.append([H.esc(r.get("title", name)), '<span class="fail">FAILED</span>',
                         f'<span class="fail">{H.esc(r.get("error", "failed"))}</span>', "", ""])
    mode = "quick" if d.config.get("quick") else "default"
    ttt = ("test-time trained DepthNet on the held-out sequence (self-supervised), "
           if d.config.get("ttt", {}).get("steps") else "")
    start = ("started from the zoo's DepthNet and ContraFeat (see Models)" if d.zoo
             else "trained DepthNet and ContraFeat on CPU")
    return (f"<p>Simulated colon, {start}, {ttt}exported to ONNX, reconstructed "
            f"the held-out sequence in {len(rows)} configurations ({mode} preset). ATE is the RMSE after Sim(3) "
            "alignment, on the registered frames.</p>"
            + H.table(["configuration", "status", "ATE (cm)", "path length (cm)", "registered (%)"], rows))


def _models(d: ReportData) -> str:
    """Which networks ran: the zoo entries with their cards' held-out numbers, or the demo's own training."""
    zoo = d.zoo or {}
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
    guard = d.ttt_guard
    said = ""
    if guard and guard.get("best_step") is None and not guard.get("events"):
        said = (f"<p>Test-time training guard: no check fell within the {guard.get('steps', 'n/a')} steps, so it "
                "did nothing; the last weights are used.</p>")
    elif guard:
        events = ", ".join(e["event"] + (f" at step {e['step']}" if "step" in e else "") for e in guard["events"])
        said = (f"<p>Test-time training guard: best weights (lowest photometric term, no ground truth) from step "
                f"{guard.get('best_step')}; events: {H.esc(events or 'none (no collapse)')}.</p>")
    return ("<p>The models this demo started from, with the held-out numbers of their model cards "
            "(<code>zoo/NAME/README.md</code>; simulator sequences this demo did not use). This run's own numbers "
            "are in the sections below.</p>"
            + H.table(["model", "kind", "what", "training", "card's held-out numbers"], rows) + said)


def _deviations(d: ReportData) -> str:
    dep = d.config["depth"]
    items = []
    if d.zoo:
        items.append("The networks come from the project's zoo: trained on the simulator with a supervised depth term "
                     "and at CPU size; each card lists its deviations from the paper (<code>zoo/NAME/README.md"
                     "</code>).")
        ttt = d.config.get("ttt", {})
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
    ttt = d.config.get("ttt", {})
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
                 f"{d.config['features']['size']} px, {d.config['features']['steps']} steps), far from the "
                 "paper's training.")
    return '<div class="note"><ul>' + "".join(f"<li>{i}</li>" for i in items) + "</ul></div>"


def _depth(d: ReportData, figs: Figures) -> str:
    m = d.metrics["depth"]
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
    fig = figs.depth
    rng = fig.get("range_m", [0, 0])
    scales = ", ".join(f"{H.esc(k)} x {_num(v, 1, 2)}" for k, v in fig.get("scales", {}).items())
    return (H.image(figs.image("figures/depth_samples.png"),
                    f"held-out frames | predicted depth ({scales}: the metric scale each export recorded, as SLAM "
                    f"uses it) | true depth; colour {_num(rng[0], 100, 1)}-{_num(rng[1], 100, 1)} cm, "
                    "black = no depth")
            + f"<p>Seven depth metrics of {which}. {len(m['frames'])} held-out frames "
              f"(median scale true/predicted: {_num(m['median_scaled'].get('scale'), 1, 3)}). Metric: depth times "
              "the scale the export measured on the training sequences.</p>"
            + H.table(head, rows))


def _matches(d: ReportData, figs: Figures) -> str:
    m = d.metrics["matches"]
    rows = [[name, m[key]["found"], m[key]["correct"], _num(m[key]["precision"], 100, 1),
             _num(m[key]["recall"], 100, 1)] for key, name in (("sift", "SIFT"), ("contrafeat", "ContraFeat"))]
    i, j = m["pair"]
    return (f"<p>Frames {i} and {j} of the held-out sequence, {m['keypoints']} SIFT keypoints, "
            f"{m['ground_truth']} ground-truth matches. Green = correct (within 2 px), yellow = near miss, "
            "red = wrong. Top row SIFT, bottom row ContraFeat.</p>"
            + H.table(["descriptor", "matches", "correct", "precision (%)", "recall (%)"], rows)
            + H.image(figs.image(m["figure"]), "SIFT (top) vs ContraFeat (bottom)"))


def _per_run(d: ReportData, figs: Figures, file: str, caption, absent: dict[str, str] | None = None) -> str:
    """One image per configuration (``slam/NAME/FILE``); ``absent``: name -> what to say instead
    when a configuration writes no such file by design."""
    out = []
    for name, r in d.metrics["slam"].items():
        title = H.esc(r.get("title", name))
        if r.get("status") != "ok":
            out.append(f'<p class="fail">{title}: failed, nothing to show ({H.esc(r.get("error", ""))})</p>')
        elif name in (absent or {}) and figs.image(f"slam/{name}/{file}").png is None:
            out.append(f"<h3>{title}</h3><p>{H.esc(absent[name])}</p>")
        else:
            out.append(f"<h3>{title}</h3>" + H.image(figs.image(f"slam/{name}/{file}"), caption(r)))
    return "".join(out)


def _meshes(d: ReportData, figs: Figures) -> str:
    out = ["<p>TSDF meshes, offscreen renders (vertex colours, light at the eye).</p>"]
    for name, r in d.metrics["slam"].items():
        files = figs.meshes.get(name, [])
        if r.get("status") != "ok" or not files:
            out.append(f'<p class="fail">{H.esc(r.get("title", name))}: no mesh to show</p>')
            continue
        out.append(f"<h3>{H.esc(r.get('title', name))}</h3>" + "".join(
            H.image(figs.image(f"figures/{f}"), f.rsplit("_", 1)[-1][:-4], 300) for f in files))
    return "".join(out)


def _view3d(d: ReportData, figs: Figures) -> str:
    """The interactive 3D view of one configuration (``d.view``) and its two videos (``figs.view``)."""
    v = d.view
    if not v:
        return '<p class="fail">No configuration gave a reconstruction to view.</p>'
    title = H.esc(v.title)
    if figs.view.error:
        return f'<p class="fail">{title}: no 3D view ({H.esc(figs.view.error)})</p>'
    cost = "; ".join(f"{H.esc(name)} {_num(ms, 1, 0)} ms per rendered frame"
                     for name, ms in figs.view.render_ms.items())
    return (f"<p>{title}, in 3D: drag to orbit, right drag to pan, wheel to zoom; switch the layers on the right. "
            f"The geometry is decimated to the report's budget ({v.budget_triangles:,} triangles); "
            f"<code>slam/{H.esc(v.run)}/view.html</code> has it at the full page budget, linked to the PLY "
            "files.</p>" + view_fragment(v.data) + H.table(["layer", "data"], layer_table_rows(v.data))
            + "<p>The input beside the reconstruction rendered from each frame's estimated pose (same intrinsics; "
              "unseen wall blue), and a fly-through of the final model along the smoothed camera path, rendered "
              f"on the CPU{f' ({cost})' if cost else ''}.</p>"
            + "".join(H.video(video, VIDEO_EMBED_MAX) for video in figs.view.videos))


def _unseen(d: ReportData, figs: Figures) -> str:
    u = d.unseen
    if u.get("source") == "run":
        # the demo measures the truth of every run (it says when it could not); a user's video has none
        measured = any(r.get("truth") for r in u["runs"]) or d.ingest is None
        out = ["<p>Share of the colon wall each run estimated it did not see, from its own trajectory and depth "
               "(<code>coverage.json</code>, no ground truth)"
               + (", beside the truth <code>c3f_slam evaluate</code> measured for the same run" if measured else "")
               + ". Maps: the wall unrolled along the explored centreline (cm), unseen in blue, seen in the wall's "
               "colour (grey: seen but no colour)" + ("; the true map of the same run below its estimate" if measured
                                                       else "") + ".</p>"]
        if not measured:
            out.append(f'<p class="note">{NO_TRUTH}</p>')
        for r in u["runs"]:
            title = H.esc(r["run"])
            if r.get("status") != "ok":
                out.append(f'<p class="fail">{title}: no estimate ({H.esc(r.get("reason") or r.get("status"))})</p>')
                continue
            truth = r.get("truth") or {}
            vs = (f" (truth {_num(truth.get('unseen_share'), 100, 1)} %, error {_num(truth.get('error_pp'), 1, 1)} pp)"
                  if truth else " (no truth measured)" if measured else "")
            segs = [[_num(s["start_m"], 100, 1), _num(s["end_m"], 100, 1), _num(s["unseen_share"], 100, 1)]
                    for s in r.get("segments", [])]
            truth_map = H.image(figs.image(r["truth_map"]), "true coverage map", 520) if r.get("truth_map") else ""
            out.append(f"<h3>{title}: <b>{_num(r['unseen_share'], 100, 1)} %</b> unseen{vs}</h3>"
                       + H.image(figs.image(r["map"]), "estimated coverage map", 520) + truth_map
                       + H.table(["from (cm)", "to (cm)", "unseen (%)"], segs))
        return "".join(out)
    shown = [r for r in u.get("runs", []) if figs.coverage.get(r.get("name"))]
    if u.get("source") == "ground_truth" and shown:
        out = ["<p><b>Ground truth</b> (not estimated by the run): the simulator's true surface near the path, "
               "painted seen (green) / unseen (red) by each reconstruction after aligning it with the ATE's "
               "transform (<code>c3f_slam evaluate</code>).</p>"]
        for r in shown:
            out.append(f"<h3>{H.esc(r['run'])}: {_num(r['seen_share'], 100, 1)} % of the whole true mesh seen</h3>"
                       + "".join(H.image(figs.image(f"figures/{f}"), f.rsplit("_", 1)[-1][:-4], 300)
                                 for f in figs.coverage[r["name"]]))
        return "".join(out)
    return '<p class="fail">No configuration gave a reconstruction to measure coverage with.</p>'


def _timings(d: ReportData) -> str:
    rows = [[name, _num(sec, 1, 1), H.esc(status)] for name, sec, status in d.timings]
    return H.table(["stage", "seconds", "status"], rows)


def _environment(d: ReportData) -> str:
    rows = [[H.esc(k), H.esc(v)] for k, v in d.environment.items()]
    return H.table(["item", "value"], rows) + f"<p>Settings: <code>{H.esc(json.dumps(d.config))}</code></p>"


def _artefacts(rows: list[tuple[str, str, str]]) -> str:
    return H.table(["file (in the demo folder)", "what", "open with"],
                   [[f"<code>{H.esc(a)}</code>", H.esc(b), H.esc(c)] for a, b, c in rows])


def _video_summary(d: ReportData) -> str:
    """What ran on the user's video and each configuration's numbers, none of them against a truth."""
    ing, ttt = d.ingest or {}, d.config.get("ttt", {})
    rows = []
    for name, r in d.metrics["slam"].items():
        title = H.esc(r.get("title", name))
        if r.get("status") != "ok":
            rows.append([title, '<span class="fail">FAILED</span>',
                         f'<span class="fail">{H.esc(r.get("error", "failed"))}</span>', "", "", ""])
            continue
        rows.append([title, "ok", _num(r.get("registered_share"), 100, 1), _num(r.get("jitter_ratio"), 1, 2),
                     _num(r.get("unseen_share"), 100, 1), _num(r.get("path_length_m"), 100, 1)])
    w, h = ing.get("size", ["?", "?"])
    tuned = (f"test-time trained the zoo's DepthNet on them ({ttt.get('steps')} steps, self-supervised), "
             if ttt.get("steps") else "")
    return (f"<p>Your video <code>{H.esc(Path(ing.get('video', '?')).name)}</code>: {ing.get('frames', 'n/a')} frames "
            f"({w}x{h} px, every {ing.get('step', '?')} of {_num(ing.get('fps'), 1, 0)} fps), {tuned}exported it "
            f"to ONNX and reconstructed the frames in {len(rows)} configurations"
            f"{' (quick preset)' if d.config.get('quick') else ''}.</p>"
            + H.table(["configuration", "status", "registered (%)", "jitter ratio", "unseen wall (%)",
                       "path length (cm, the run's scale)"], rows)
            + f'<p class="note">{NO_TRUTH}</p>')


def _input(d: ReportData) -> str:
    """The video, how its frames were sampled and resized, and where the intrinsics came from."""
    ing = d.ingest or {}
    cam, limits = ing.get("camera", {}), ing.get("settings", {})
    hfov = 2 * math.degrees(math.atan(cam["width"] / (2 * cam["fx"]))) if cam.get("fx") else None
    (sw, sh), (w, h) = ing.get("source_size", ["?", "?"]), ing.get("size", ["?", "?"])
    statuses = ", ".join(f"{H.esc(k)} {v}" for k, v in (ing.get("statuses") or {}).items())
    used = (f"{ing.get('frames', 'n/a')}: every {ing.get('step', '?')} from the start (at most "
            f"{_num(limits.get('max_fps'), 1, 0)} per second of video, at most {limits.get('max_frames', '?')}), "
            f"{_num(ing.get('seconds'), 1, 1)} s of video, resized to {w}x{h} px; frame status: {statuses}")
    intrinsics = (f"{H.esc(ing.get('camera_source', 'n/a'))}; after resizing fx {_num(cam.get('fx'), 1, 1)}, "
                  f"fy {_num(cam.get('fy'), 1, 1)}, cx {_num(cam.get('cx'), 1, 1)}, cy {_num(cam.get('cy'), 1, 1)} "
                  f"px (horizontal field of view {_num(hfov, 1, 0)} degrees)")
    rows = [["video", f"<code>{H.esc(ing.get('video', 'n/a'))}</code>, {sw}x{sh} px, {_num(ing.get('fps'), 1, 2)} "
                      f"fps, {ing.get('video_frames', 'n/a')} frames"],
            ["frames used", used], ["intrinsics", intrinsics]]
    if ing.get("truncated"):
        rows.append(["note", f'<span class="fail">{H.esc(ing["truncated"])}</span>'])
    guess = "fov guess" in str(ing.get("camera_source", ""))
    return (H.table(["item", "value"], rows)
            + ("<p>The intrinsics are a guess from the field of view: lengths and the unseen share depend on it; "
               "calibrate the scope (<code>python -m c3f_slam calibrate</code>) to trust them.</p>" if guess else ""))


def _tissue(d: ReportData, figs: Figures) -> str:
    """The tissue area each run found (summary.json ``tissue_mask``) and the mask over a frame."""
    rows = []
    for name, r in d.metrics["slam"].items():
        t = r.get("tissue_mask") or {}
        rows.append([H.esc(r.get("title", name)), _num(t.get("share"), 100, 1), H.esc(t.get("source", "n/a")),
                     t.get("frames", ""), _num(t.get("overlay_share"), 100, 2)])
    fig = figs.tissue
    whole = any(str((r.get("tissue_mask") or {}).get("source", "")).startswith("whole frame")
                for r in d.metrics["slam"].values())
    shown = (H.image(figs.image(f"figures/{fig['figure']}"), f"frame {fig['frame']}: outside the tissue area tinted "
                     "magenta, its outline yellow", 520) if fig else
             "<p>The runs used the whole frame: no border or overlay was found.</p>" if whole else
             '<p class="fail">No run got as far as finding the tissue area.</p>')
    found = (d.ingest or {}).get("tissue_mask") or {}
    where = (f"found by the ingest from {found.get('frames', 0)} frames of the video and named by the sequence's "
             "<code>camera.json</code>, where each run read it" if found.get("file")
             else "as the runtime found it before the first frame, or read it from a mask file")
    return (f"<p>The image area that shows tissue, {where} (the scope's "
            "border and burned-in overlays left out of depth, keypoints, fusion, the unseen wall and test-time "
            "training's losses; <code>tissue_mask.png</code> in each run folder).</p>"
            + H.table(["configuration", "tissue (% of the image)", "source", "frames used", "overlays (%)"], rows)
            + shown)


def _frames(d: ReportData, figs: Figures) -> str:
    """What became of each frame, per configuration: registered, not registered, skipped per cause."""
    out = ["<p>Each frame of the run is registered in the main map, processed but not registered (tracking lost "
           "it, or it is in a component the map could not join), or skipped before tracking (its cause, "
           "summary.json <code>skipped_*</code>). The back-end's decisions on the processed frames are "
           "summary.json's <code>frame_decisions</code>.</p>"]
    for name, r in d.metrics["slam"].items():
        title = H.esc(r.get("title", name))
        if "frames" not in r:
            out.append(f'<p class="fail">{title}: no summary.json ({H.esc(r.get("error", ""))})</p>')
            continue
        fig = figs.frames.get(name)
        how = ("each frame in order, from the run's frame_log.csv" if (fig or {}).get("kind") == "timeline"
               else "the counts, grouped (the run wrote no per-frame log)")
        skipped = ", ".join(f"{H.esc(k)} {v}" for k, v in (r.get("skipped") or {}).items())
        decisions = ", ".join(f"{H.esc(k)} {v}" for k, v in (r.get("frame_decisions") or {}).items())
        out.append(f"<h3>{title}: {_num(r.get('registered_share'), 100, 1)} % registered "
                   f"({_num(r.get('registered_share_of_usable'), 100, 1)} % of the frames not skipped)</h3>"
                   + H.table(["frames", "processed", "registered", "skipped by cause", "decisions"],
                             [[r.get("frames"), r.get("processed"), r.get("registered_frames"), skipped, decisions]])
                   + (H.image(figs.image(f"figures/{fig['figure']}"), how) if fig else ""))
    return "".join(out)


def _jitter(d: ReportData) -> str:
    """The jitter ratio of each configuration's trajectory (no ground truth needed)."""
    rows = [[H.esc(r.get("title", name)), _num(r.get("jitter_ratio"), 1, 2), _num(r.get("path_length_m"), 100, 1),
             _num(r.get("seconds"), 1, 1)]
            for name, r in d.metrics["slam"].items() if r.get("status") == "ok"]
    return ("<p>Jitter ratio: the camera path's length over the length of its 1-s moving average "
            "(<code>c3f_slam.evaluation.trajectory.jitter_ratio</code>, each frame at its time in the video). 1 is a "
            "smooth path; a scope moves smoothly at this time scale, so a ratio well above 1 is shake of the "
            "estimate (wrong matches, depth that changes scale from frame to frame). It says nothing of drift or "
            "of a wrong scale, which stay smooth.</p>"
            + H.table(["configuration", "jitter ratio", "path length (cm, the run's scale)", "seconds of video"], rows)
            if rows else '<p class="fail">No configuration gave a trajectory.</p>')


#: what the numbers of a user's video can and cannot say (the report says it where they are shown)
NO_TRUTH = ("Without ground truth these numbers describe the map, not its accuracy: the registered share and the "
            "jitter ratio say how much of the video the map holds and how smoothly its camera moves, and the unseen "
            "share is measured on the map's own wall model, so a wrong depth scale, wrong intrinsics or a trajectory "
            "that drifts smoothly would change the geometry without showing here. Compare the two configurations "
            "with each other; the simulator's accuracy figures (the demo, docs/zoo.md) do not transfer to this "
            "video.")


def build_report(d: ReportData, figs: Figures) -> str:
    """HTML of the report from the collected data and the figures drawn from it: the demo's
    sections (:data:`SECTIONS`), or for ``d.variant`` ``video`` (a user's video) those without the
    ground-truth sections (:data:`VIDEO_SECTIONS`)."""
    video = d.variant == "video"
    parts = _video_parts(d, figs) if video else _demo_parts(d, figs)
    tail = view_scripts() if d.view and d.view.data and not figs.view.error else ""
    title = ("C3Fusion report: " + Path((d.ingest or {}).get("video", "video")).name if video
             else "C3Fusion demo report")
    return H.page(title, [H.section(sid, *parts[sid]) for sid in parts], tail)


def _shared_parts(d: ReportData, figs: Figures) -> dict[str, tuple[str, str]]:
    """The sections both variants have: models, meshes, 3D view, unseen surface, times, environment."""
    return {"models": ("Models", _models(d)), "meshes": ("Reconstructed meshes", _meshes(d, figs)),
            "view3d": ("3D view and videos", _view3d(d, figs)), "unseen": ("Unseen surface", _unseen(d, figs)),
            "timings": ("Time per stage", _timings(d)), "environment": ("Versions, machine, seeds", _environment(d))}


def _demo_parts(d: ReportData, figs: Figures) -> dict[str, tuple[str, str]]:
    """The demo's sections (:data:`SECTIONS`), in order."""
    ate = lambda r: f"ATE {_num(r.get('ate_sim3_m'), 100, 2)} cm, path {_num(r.get('gt_length_m'), 100, 1)} cm"  # noqa: E731
    parts = {
        **_shared_parts(d, figs),
        "summary": ("Summary", _summary(d)),
        "deviations": ("Deviations from the paper", _deviations(d)),
        "depth": ("Depth", _depth(d, figs)),
        "matches": ("Matches: SIFT vs ContraFeat", _matches(d, figs)),
        "trajectories": ("Trajectories vs ground truth", _per_run(d, figs, "trajectory.png", ate)),
        "keyframe-graph": ("Keyframe connectivity graph", _per_run(
            d, figs, "keyframe_graph.png", lambda r: "",
            {"odometry": "No keyframe graph: frame-to-frame odometry chains each frame to the one before."})),
        "artefacts": ("Files in this folder", _artefacts(ARTEFACTS)),
    }
    return {sid: parts[sid] for sid in SECTIONS}


def _video_parts(d: ReportData, figs: Figures) -> dict[str, tuple[str, str]]:
    """The sections of a user's video (:data:`VIDEO_SECTIONS`), in order."""
    parts = {
        **_shared_parts(d, figs),
        "summary": ("Summary", _video_summary(d)),
        "input": ("The video", _input(d)),
        "tissue": ("Tissue area", _tissue(d, figs)),
        "frames": ("Frames: registered and skipped", _frames(d, figs)),
        "trajectories": ("Trajectory smoothness", _jitter(d)),
        "keyframe-graph": ("Keyframe connectivity graph", _per_run(d, figs, "keyframe_graph.png", lambda r: "")),
        "artefacts": ("Files in this folder", _artefacts(VIDEO_ARTEFACTS)),
    }
    return {sid: parts[sid] for sid in VIDEO_SECTIONS}
