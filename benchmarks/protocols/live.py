"""The live view: delay, dropped frames, the unseen wall's update cost, memory over a long recording.

Cases (zoo models v1, ``--depth-model zoo:c3f-depth-r18w32 --feature-model zoo:c3f-features-r18w32``):

- ``live-128`` / ``live-256``: a simulator sequence (preset seq1, a seed no other benchmark uses)
  at 128 and 256 px, delivered at ``rate`` frames per second by ``python -m c3f_slam live``'s
  pipeline (in this process, :func:`c3f_slam.live.loop.run_live`), with a headless Chromium
  showing the page meanwhile (its display delays come back through the page's reports); then
  ``python -m c3f_slam run`` on the same frames, all of them, for the final unseen share;
- ``long-128``: ``long_frames`` frames at ``rate`` frames per second: a ``long_base`` -frame
  sequence at 128 px played forward and backward (ping-pong, symbolic links), no page; resident
  memory and counters every ``every`` delivered frames.

Per case: frames delivered, taken and dropped; frames per second taken; the delay from a frame's
capture (delivery) to its publication for the page and to its display in the page (median, 95th
percentile); the live unseen-wall estimate at the end against the live run's own end-of-run
estimate and ``run``'s; the update cost of the unseen wall per frame against the length mapped.
Everything runs on the machine's cores beside whatever else runs there (the load is printed).

    python -m benchmarks.protocols.live --report benchmarks/results/live.md
    python -m benchmarks.protocols.live --set long_frames=2000 --set sizes=128 --report /tmp/live.md

Settings (``--print-config``: each with its default and meaning): :class:`Settings`.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from benchmarks.common import RESULTS, WORK
from benchmarks.common.protocol_cli import REPORT_HELP, WORK_HELP, ProtocolCli
from benchmarks.common.report import Report
from benchmarks.common.simulate import SimSequence, ensure_sequence
from benchmarks.common.slam_run import run_kept
from benchmarks.protocols.slam_scale import ping_pong, rss_mb
from c3f_slam.config import SlamConfig
from c3f_slam.live.loop import MAX_TRACKS, LiveRun, run_live
from c3f_slam.live.settings import LiveSettings
from c3f_slam.pipeline.run_evaluation import evaluate_run
from c3f_slam.pipeline.sources import RunInputs

MODELS = ["--depth-model", "zoo:c3f-depth-r18w32", "--feature-model", "zoo:c3f-features-r18w32"]
SEED = 7701  #: the simulator seed of the live cases (no other benchmark uses it)
BROWSER_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader", "--hide-scrollbars",
                 "--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE 127.0.0.1", "--remote-debugging-port=0",
                 "--window-size=1280,800")


@dataclass(frozen=True)
class Settings:
    """What the live protocol measures."""

    sizes: str = "128,256"  #: frame sizes (pixels) of the live cases, comma-separated
    frames: int = 600  #: frames of each live case's sequence
    rate: float = 30.0  #: frames per second the source delivers
    long_frames: int = 20000  #: frames of the long recording (0: no long case)
    long_base: int = 300  #: frames of the sequence the long recording plays forward and backward
    every: int = 1000  #: delivered frames between two memory samples of the long case
    page: bool = True  #: open the page in headless Chromium during the live cases (display delay)


class Sampled(LiveRun):
    """A live run that records memory and counters every ``every`` delivered frames."""

    def __init__(self, *args, every: int, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.every, self.samples, self._next = every, [], every

    def stepped(self, run, item, outcome, decision) -> None:
        super().stepped(run, item, outcome, decision)
        src = self.source
        if src is not None and src.delivered >= self._next:
            self._next += self.every
            self.samples.append({"delivered": src.delivered, "taken": self.taken, "dropped": src.dropped,
                                 "rss_mb": rss_mb(), "map_parts": len(self.tracks),
                                 "wall_rows": sum(t.wall.n_rows for t in self.tracks.values()),
                                 "map_points": sum(len(t.keys) for t in self.tracks.values()),
                                 "keyframes": run.backend.map.n_keyframes(),
                                 "waiting_points": sum(len(t.wall.wait_xyz) for t in self.tracks.values())})


def _browser() -> str | None:
    return next((p for p in (shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome")) if p), None)


class Page:
    """A headless Chromium showing the page while the run lasts (None without a browser)."""

    def __init__(self) -> None:
        self.proc: subprocess.Popen | None = None
        self.profile = tempfile.mkdtemp(prefix="c3f-live-page-")

    def open(self, url: str) -> None:
        browser = _browser()
        if browser is not None:
            self.proc = subprocess.Popen([browser, *BROWSER_FLAGS, f"--user-data-dir={self.profile}", url],
                                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)

    def close(self) -> None:
        if self.proc is not None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
        shutil.rmtree(self.profile, ignore_errors=True)


def live_case(name: str, source: Path, out: Path, settings: Settings, *, page: bool, every: int) -> dict:
    """One live run of ``source`` into ``out`` (replaced); its live.json, summary and samples."""
    cfg = SlamConfig()
    live_settings = LiveSettings(port=0, rate=settings.rate, linger=0)
    inputs = RunInputs(depth_model="zoo:c3f-depth-r18w32", feature_model="zoo:c3f-features-r18w32")
    browser = Page() if page else None

    class _Run(Sampled):
        def opened(self, run) -> None:
            super().opened(run)
            if browser is not None:
                browser.open(self.server.url)

    live = _Run(live_settings, cfg, every=every, echo=lambda line: print(f"[{name}] {line}", flush=True))
    t0, load0 = time.perf_counter(), os.getloadavg()[0]
    try:
        summary, live = run_live(source, out, cfg, inputs, live_settings, overwrite=True, live=live)
    finally:
        if browser is not None:
            browser.close()
    rec = json.loads((out / "live.json").read_text())
    return {"name": name, "live": rec, "summary": {k: summary.get(k) for k in (
        "frames", "registered_share", "unseen_share", "status")}, "samples": live.samples,
            "wall_s": time.perf_counter() - t0, "load": [load0, os.getloadavg()[0]], "page": page}


def _pct(x) -> str:
    return "n/a" if x is None else f"{100 * x:.1f}"


def _ms(d: dict | None, key: str) -> str:
    v = (d or {}).get(key)
    return "n/a" if v is None else f"{v:.0f}"


def report_body(settings: Settings, cases: list[dict]) -> list[str]:
    rows, cost_rows, mem_rows = [], [], []
    for c in cases:
        rec, s = c["live"], c["summary"]
        d = rec.get("delays_ms") or {}
        pub, disp = d.get("capture_to_publish_ms"), d.get("capture_to_display_ms")
        taken_fps = rec["frames_taken"] / c["wall_s"] if c["wall_s"] > 0 else 0.0
        rows.append(f"| {c['name']} | {rec['frames_delivered']} | {rec['frames_taken']} | "
                    f"{100 * rec['dropped_share']:.1f} | {taken_fps:.1f} | {_ms(pub, 'median')} / {_ms(pub, 'p95')} | "
                    + (f"{_ms(disp, 'median')} / {_ms(disp, 'p95')}" if c["page"] else "no page")
                    + f" | {_pct(rec['unseen_share_live'])} | {_pct(s.get('unseen_share'))} | "
                    f"{_pct(c.get('truth', {}).get('truth_registered'))} | {_pct(c.get('run_unseen_share'))} | "
                    f"{_pct(c.get('run_truth', {}).get('truth_registered'))} | {len(rec['alerts'])} | "
                    f"{c['load'][0]:.1f} / {c['load'][1]:.1f} |")
        for b in rec["unseen_wall_update"]:
            cost_rows.append(f"| {c['name']} | {100 * b['mapped_from_m']:.0f}-{100 * b['mapped_to_m']:.0f} | "
                             f"{b['updates']} | {b['mean_ms']:.1f} | {b['max_ms']:.1f} | "
                             f"{b['mean_rows_changed']:.0f} |")
        for m in c["samples"]:
            mem_rows.append(f"| {c['name']} | {m['delivered']} | {m['taken']} | {m['dropped']} | {m['rss_mb']:.0f} | "
                            f"{m['map_parts']} | {m['wall_rows']} | {m['map_points']} | {m['waiting_points']} | "
                            f"{m['keyframes']} |")
    return [
        f"- Source: frames delivered at {settings.rate:g} frames/s (newest frame wins: a frame still waiting when the "
        "next arrives is dropped); zoo models v1 (depth and descriptors); the page's map, wall and alerts as "
        "`python -m c3f_slam live` serves them. Live cases: preset seq1, seed "
        f"{SEED}, {settings.frames} frames; the long case plays a {settings.long_base}-frame sequence forward and "
        f"backward to {settings.long_frames} frames. 2 CPU cores shared with the page's browser (SwiftShader WebGL) "
        "and whatever else runs (load average before / after).",
        "- Delays in ms: capture (the source delivers the frame) to publication for the page, and to its display "
        "in the page (the page reports the time it showed the image: same machine, same clock). Unseen wall %: the "
        "live estimate at the end (of its longest map part), the live run's end-of-run estimate (its run folder, "
        "from the frames it took), `run` on every frame of the same input; the truth (the simulator's mesh seen "
        "from the true poses of the frames the run registered in its main map, `evaluate --gt`) beside each.", "",
        "| case | delivered | taken | dropped % | taken/s | capture to page ms (median / p95) | capture to display "
        "ms (median / p95) | unseen live % | unseen, live run's folder % | truth, its frames % | unseen, `run` % | "
        "truth, `run`'s frames % | alerts | load |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
        *rows, "",
        "Unseen-wall update per frame against the length of centreline mapped (cm): updates, mean and max ms, rows "
        "changed per update.", "",
        "| case | mapped cm | updates | mean ms | max ms | rows changed |", "|---|---|---|---|---|---|",
        *cost_rows, "",
        "Memory over the long recording, every "
        f"{settings.every} delivered frames: resident memory of the process (run, page server, state), the map "
        f"parts whose live wall is kept (at most {MAX_TRACKS}), their wall rows, the points of the page's map in "
        "them, the points waiting beyond their last wall row, keyframes.", "",
        "| case | delivered | taken | dropped | RSS MB | map parts | wall rows | map points | waiting points | "
        "keyframes |",
        "|---|---|---|---|---|---|---|---|---|---|",
        *mem_rows,
    ]


def _truth(run: Path, seq: Path) -> dict:
    """The simulator's true unseen shares for a run folder (``evaluate --gt``): of every frame's
    true pose, and of the frames the run registered only."""
    try:
        u = evaluate_run(run, seq).get("unseen") or {}
    except Exception as exc:  # noqa: BLE001 -- a failed evaluation is reported, not fatal
        return {"error": str(exc)}
    return {"truth": u.get("truth"), "truth_registered": u.get("truth_registered")}


CLI = ProtocolCli("live", Settings, __doc__, example="long_frames=2000")


def main(argv: list[str] | None = None) -> None:
    ap = CLI.parser()
    ap.add_argument("--work", type=Path, default=WORK / "live", help=WORK_HELP)
    ap.add_argument("--report", type=Path, default=RESULTS / "live.md", help=REPORT_HELP)
    args, settings = CLI.parse(ap, argv)
    cases = []
    for size in [int(s) for s in settings.sizes.split(",") if s.strip()]:
        seq = ensure_sequence(SimSequence("seq1", SEED, settings.frames, size), args.work / f"seq_{size}")
        case = live_case(f"live-{size}", seq, args.work / f"live_{size}", settings, page=settings.page,
                         every=settings.frames + 1)
        case["run_unseen_share"] = run_kept(seq, args.work / f"run_{size}", MODELS).get("unseen_share")
        case["truth"] = _truth(args.work / f"live_{size}", seq)
        case["run_truth"] = _truth(args.work / f"run_{size}", seq)
        cases.append(case)
    if settings.long_frames > 0:
        base = ensure_sequence(SimSequence("seq1", SEED + 1, settings.long_base, 128), args.work / "long_base")
        long_seq = args.work / f"long_{settings.long_frames}"
        if not (long_seq / "camera.json").is_file():
            ping_pong(base, long_seq, settings.long_frames)
        cases.append(live_case("long-128", long_seq, args.work / "live_long", settings, page=False,
                               every=settings.every))
    report = Report(__file__, "The live view: delay, dropped frames, unseen-wall updates, memory", argv)
    print(report.publish(args.report, report_body(settings, cases), settings, data={"cases": cases}, options=args))


if __name__ == "__main__":
    main()
