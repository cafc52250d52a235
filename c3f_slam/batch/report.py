"""The summary of a batch, written atomically into its output folder:

- ``batch.json``: the options, the settings tree every run started from (``config``, as a run's
  summary.json has it: ``batch --config OUT/batch.json`` replays it), the counts by status and
  one row per sequence (:class:`c3f_slam.batch.job.Row`: lengths in metres, times in seconds,
  shares 0..1);
- ``batch.csv``: the rows, one line each, the same columns;
- ``index.html``: a table of the runs (one page, no outside file), ATE in cm, shares in %,
  each run's name a link to its folder and its figures shown where it has them.
"""

from __future__ import annotations

import csv
import html
import io
import math
from dataclasses import fields
from pathlib import Path

from c3f_core.atomic import atomic_write_text
from c3f_slam.batch.job import STATUSES, Row
from c3f_slam.io.run_outputs import write_json

JSON_NAME, CSV_NAME, HTML_NAME = "batch.json", "batch.csv", "index.html"
COLUMNS = tuple(f.name for f in fields(Row))
#: figures of a run folder shown in the index when present
FIGURES = ("trajectory.png", "keyframe_graph.png", "coverage_map.png")


def counts(rows: list[Row]) -> dict[str, int]:
    return {s: sum(r.status == s for r in rows) for s in STATUSES}


def _csv(rows: list[Row]) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, COLUMNS, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: "" if v is None else v for k, v in r.as_dict().items()})
    return buf.getvalue()


def _number(value: float | None, scale: float = 1.0, digits: int = 1) -> str:
    if value is None or not math.isfinite(value):
        return "-"
    return f"{scale * value:.{digits}f}"


def _html_row(r: Row, out: Path) -> str:
    e = html.escape
    run = Path(r.run)
    link = run.relative_to(out) if run.is_relative_to(out) else run
    figures = " ".join(f'<a href="{e(str(link / f))}"><img src="{e(str(link / f))}" alt="{e(f)}"></a>'
                       for f in FIGURES if (run / f).is_file())
    note = e(r.error or r.evaluation_error or "")
    cells = [f'<a href="{e(str(link))}/summary.json">{e(r.name)}</a>', e(r.status), str(r.frames or "-"),
             str(r.registered_frames if r.registered_frames is not None else "-"),
             _number(r.registered_share, 100), _number(r.ate_rmse_m, 100, 2), _number(r.unseen_share, 100),
             _number(r.seconds), str(r.attempts), note, figures]
    return f'<tr class="{e(r.status)}">' + "".join(f"<td>{c}</td>" for c in cells) + "</tr>"


def _html(rows: list[Row], out: Path, title: str) -> str:
    head = ["run", "status", "frames", "registered", "registered %", "ATE cm (Sim3)", "unseen wall %", "time s",
            "attempts", "error", "figures"]
    c = counts(rows)
    style = ("body{font-family:sans-serif;margin:1.5em}table{border-collapse:collapse;font-size:14px}"
             "td,th{border:1px solid #ccc;padding:3px 6px;text-align:left;vertical-align:top}"
             "tr.failed{background:#fde2e2}tr.skipped{color:#555}img{height:90px}")
    return "\n".join([
        "<!DOCTYPE html>", '<html><head><meta charset="utf-8">', f"<title>{html.escape(title)}</title>",
        f"<style>{style}</style></head><body>", f"<h1>{html.escape(title)}</h1>",
        f"<p>{len(rows)} sequences: {c['ok']} run, {c['skipped']} complete from an earlier batch, "
        f"{c['failed']} failed. Summary: <a href=\"{JSON_NAME}\">{JSON_NAME}</a>, "
        f"<a href=\"{CSV_NAME}\">{CSV_NAME}</a>.</p>",
        "<table><tr>" + "".join(f"<th>{h}</th>" for h in head) + "</tr>",
        *(_html_row(r, out) for r in rows), "</table></body></html>", ""])


def write_summary(out: str | Path, rows: list[Row], settings: dict, wall_seconds: float,
                  complete: bool = True, config: dict | None = None) -> None:
    """``batch.json``, ``batch.csv`` and ``index.html`` of ``rows`` in ``out`` (each atomically);
    ``settings``: the command's options; ``config``: the settings tree as nested dicts (before each
    run derives its frame-size thresholds); ``complete``: False when the batch was interrupted (the
    rows so far); ``wall_seconds`` in seconds."""
    out = Path(out)
    record = {"complete": complete, "settings": settings, "config": config, "counts": counts(rows),
              "wall_seconds": wall_seconds, "runs": [r.as_dict() for r in rows]}
    write_json(out / JSON_NAME, record)
    atomic_write_text(out / CSV_NAME, _csv(rows))
    title = f"C3Fusion batch: {settings.get('dataset', out)}"
    atomic_write_text(out / HTML_NAME, _html(rows, out, title))


__all__ = ["COLUMNS", "CSV_NAME", "HTML_NAME", "JSON_NAME", "counts", "write_summary"]
