"""The ``report`` stage: ``DIR/report.html`` in three one-way steps, each once: collect the data
(:func:`c3f_demo.collect.collect`), draw the figures from it (:func:`c3f_demo.figures.make_figures`),
write the HTML from both (:func:`c3f_demo.report.build_report`). :class:`VideoReport`: its variant
on a user's video (no ground truth)."""

from __future__ import annotations

from c3f_core.atomic import atomic_write_text
from c3f_demo.collect import collect
from c3f_demo.context import DemoContext
from c3f_demo.figures import make_figures
from c3f_demo.report import build_report
from c3f_demo.stages import Stage
from c3f_slam.io.run_outputs import write_json


def write_report(ctx: DemoContext, done: dict | None = None) -> dict:
    """collect -> figures -> HTML into ``DIR/report.html``; on a user's video also
    ``metrics/slam.json`` (each run's numbers, :func:`c3f_demo.video.run_metrics`)."""
    data = collect(ctx, done)
    if data.variant == "video":
        write_json(ctx.root / "metrics" / "slam.json", data.metrics["slam"])
    figures = make_figures(data, ctx.root)
    atomic_write_text(ctx.root / "report.html", build_report(data, figures))
    return {"report": "report.html"}


class Report(Stage):
    """Figures and ``DIR/report.html``."""

    name = "report"
    upstream = ("evaluate",)

    def settings(self, cfg):
        return {"sample_frames": cfg.report.sample_frames, "render_size": cfg.report.render_size}

    def outputs(self, ctx):
        return [ctx.root / "report.html"]

    def estimate_s(self, cfg):
        return 40.0  # figures, and the 3D view's videos (about 45 ms per rendered frame)

    def run(self, ctx, done=None):
        return write_report(ctx, done)


class VideoReport(Report):
    """``DIR/report.html`` of a user's video: the demo's report without its ground-truth sections,
    with the tissue mask, the frames per cause, the registered share and the jitter ratio of each
    run (``metrics/slam.json``)."""

    upstream = ("view",)
