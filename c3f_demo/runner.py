"""Runs the demo's stages in order into one folder, skipping those already done with the same
settings (:mod:`c3f_demo.state`), with a progress line per stage and a time table. The run's whole
settings tree goes into ``DIR/demo_state.json`` (``config``; ``--config`` that file replays it)."""

from __future__ import annotations

import sys
import time
from pathlib import Path

from c3f_core.settings import tree_as_mapping
from c3f_demo.config import DemoConfig
from c3f_demo.context import DemoContext, StageFailed, check_out_dir
from c3f_demo.evaluation import Evaluate
from c3f_demo.progress import StageLine, time_table
from c3f_demo.report_stage import Report, VideoReport
from c3f_demo.stages import Export, Simulate, Slam, Stage, TestTimeTrain, TrainDepth, TrainFeatures
from c3f_demo.state import DemoState, stage_key
from c3f_demo.video import Ingest, View

STAGES: tuple[Stage, ...] = (Simulate(), TrainDepth(), TestTimeTrain(), TrainFeatures(), Export(), Slam(),
                             Evaluate(), Report())
#: the stages on a user's video (``--video``): its frames instead of the simulator, no evaluation
#: against a truth, the 3D views, the report without ground truth
VIDEO_STAGES: tuple[Stage, ...] = (Ingest(), TrainDepth(), TestTimeTrain(), TrainFeatures(), Export(), Slam(),
                                   View(), VideoReport())


def stages_for(cfg: DemoConfig) -> tuple[Stage, ...]:
    """The stages of ``cfg``, in run order: :data:`VIDEO_STAGES` on a video, else :data:`STAGES`."""
    return VIDEO_STAGES if cfg.video else STAGES


def downstream(name: str, cfg: DemoConfig | None = None) -> list[str]:
    """``name`` and every stage of ``cfg`` (default: the demo's) that reads from it, directly or not
    (the stages are in run order)."""
    cfg = cfg or DemoConfig()
    names = [name]
    for stage in stages_for(cfg):
        if stage.name not in names and any(u in names for u in stage.inputs(cfg)):
            names.append(stage.name)
    return names


class DemoInterrupted(Exception):
    """Ctrl-C during a stage (the message names it)."""


def run_demo(root: Path, cfg: DemoConfig, overwrite: bool = False, stream=None) -> list[tuple[str, float, str]]:
    """Run every stage into ``root``; returns the time table rows (stage, seconds, status).

    Raises InputError (a stage done with other settings, a folder that is no demo folder),
    StageFailed (a command failed) or DemoInterrupted (Ctrl-C)."""
    stream = stream or sys.stdout
    check_out_dir(root)
    state = DemoState(root, overwrite, tree_as_mapping(cfg))  # the settings, replayable (--config)
    root.mkdir(parents=True, exist_ok=True)
    ctx = DemoContext(root, cfg)
    keys: dict[str, str] = {}
    timings: list[tuple[str, float, str]] = []
    stages = stages_for(cfg)
    for k, stage in enumerate(stages, 1):
        key = keys[stage.name] = stage_key(stage.settings(cfg), [keys[u] for u in stage.inputs(cfg)])
        if state.is_done(stage.name, key):
            timings.append((stage.name, state.stages[stage.name]["seconds"], "skipped (done earlier, same settings)"))
            print(f"[{k}/{len(stages)}] {stage.name:<15} skipped: done earlier with the same settings",
                  file=stream, flush=True)
            continue
        state.forget(downstream(stage.name, cfg))
        state.save()  # the settings of this run, from its first stage that runs
        stage.clean(ctx)
        done = {"notes": {n: state.notes(n) for n in state.stages}, "timings": list(timings)}
        start = time.monotonic()
        try:
            with StageLine(k, len(stages), stage.name, stage.estimate_s(cfg), stage.probe(ctx), stream):
                notes = stage.run(ctx, done)
        except KeyboardInterrupt:
            raise DemoInterrupted(f"interrupted in stage {stage.name}; the stages before it are kept, "
                                  "rerun the same command to resume") from None
        seconds = time.monotonic() - start
        state.record(stage.name, key, seconds, notes)
        timings.append((stage.name, seconds, "ran"))
    state.save()
    print(time_table(timings), file=stream, flush=True)
    print(f"report: {root / 'report.html'}", file=stream, flush=True)
    return timings


__all__ = ["STAGES", "VIDEO_STAGES", "DemoInterrupted", "StageFailed", "run_demo", "stages_for"]
