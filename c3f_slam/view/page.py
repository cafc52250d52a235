"""HTML of the 3D view: one self-contained file (three.js, the viewer and the geometry inlined), no
network, so it opens offline in any browser with WebGL.

:func:`view_fragment` is the viewer's element and data, :func:`view_scripts` the scripts a page
includes once (the demo report embeds both); :func:`view_page` is ``view.html``.
"""

from __future__ import annotations

import html
import json
from pathlib import Path

import numpy as np

from c3f_slam.view.layers import Layer
from c3f_slam.view.raycast import principal_axes

ASSETS = Path(__file__).parent
THREE_JS = ASSETS / "vendor" / "three.view.min.js"
VIEWER_JS = ASSETS / "viewer.js"
VIEW_CSS = """.c3f-view{position:relative;display:flex;gap:0;height:70vh;max-height:760px;min-height:420px;
border:1px solid #444;background:#1d2127;color:#eee;font:14px sans-serif}
.c3f-canvas{flex:1;min-width:0;position:relative}
.c3f-canvas canvas{display:block;width:100%!important;height:100%!important}
.c3f-panel{width:240px;padding:.6em;overflow:auto;border-left:1px solid #444}
.c3f-panel label{display:block;margin:.25em 0;cursor:pointer}
.c3f-swatch{display:inline-block;width:.8em;height:.8em;margin-left:.3em;border:1px solid #888}
.c3f-panel button{margin-top:.4em}.c3f-help{margin-top:.6em;font-size:12px;color:#aaa}"""


def view_data(layers: list[Layer], caption: str = "") -> dict:
    """The viewer's JSON: layers, a caption and the initial view: across the longest axis of the
    geometry (``view_direction`` centre -> eye, ``view_up``), framing the box of the geometry in
    its principal axes (``centre``, metres; ``view_extent``: half sizes across, up and along the
    view, metres)."""
    pts = np.concatenate([lay.positions for lay in layers]) if layers else np.zeros((0, 3))
    d = {"layers": [lay.to_json() for lay in layers], "caption": caption}
    if len(pts) >= 3:
        pts = np.asarray(pts, np.float64)
        a = principal_axes(pts)
        local = (pts - pts.mean(axis=0)) @ a.T
        lo, hi = local.min(axis=0), local.max(axis=0)
        d["centre"] = (pts.mean(axis=0) + (lo + hi) / 2 @ a).tolist()
        d["view_direction"], d["view_up"] = a[1].tolist(), a[2].tolist()
        d["view_extent"] = ((hi - lo) / 2)[[0, 2, 1]].tolist()
    return d


def _script_json(data: dict) -> str:
    """JSON that cannot end its <script> element early."""
    return json.dumps(data, separators=(",", ":")).replace("</", "<\\/")


def view_fragment(data: dict, source_id: str = "c3f-view-data") -> str:
    """The viewer's element and its data (a JSON script element with id ``source_id``)."""
    return (f'<div class="c3f-view" data-source="{html.escape(source_id)}"></div>\n'
            f'<script type="application/json" id="{html.escape(source_id)}">{_script_json(data)}</script>\n')


def view_scripts() -> str:
    """three.js and the viewer, inlined, and the viewer's style (once per page, after the fragments)."""
    return (f"<style>{VIEW_CSS}</style>\n<script>{THREE_JS.read_text()}</script>\n"
            f"<script>{VIEWER_JS.read_text()}</script>\n")


def layer_table_rows(data: dict) -> list[list[str]]:
    """[label, note] (HTML-escaped) of each layer of the viewer's JSON :func:`view_data`."""
    return [[html.escape(lay["label"]), html.escape(lay["note"])] for lay in data["layers"]]


def layer_table(data: dict) -> str:
    """An HTML table: each layer and where its data came from (decimated or not)."""
    rows = "".join(f"<tr><td>{a}</td><td>{b}</td></tr>" for a, b in layer_table_rows(data))
    return f"<table><tr><th>layer</th><th>data</th></tr>{rows}</table>"


def video_element(src: str, caption: str, name: str) -> str:
    """A ``<figure>`` with a looping, muted ``<video>`` of ``src`` (a relative path or a data URI)."""
    return (f'<figure><video controls muted loop playsinline preload="auto" data-name="{html.escape(name)}" '
            f'src="{html.escape(src)}"></video><figcaption>{html.escape(caption)}</figcaption></figure>')


PAGE_STYLE = """body{font-family:sans-serif;margin:1em 2em;color:#222}table{border-collapse:collapse;margin:.6em 0}
td,th{border:1px solid #ccc;padding:.2em .5em;text-align:left;font-size:13px}figure{display:inline-block;margin:.4em;
vertical-align:top}video{max-width:100%;background:#000}figcaption{font-size:.85em;color:#555}"""


def view_page(title: str, intro: str, data: dict, extra: str = "") -> str:
    """``view.html``: the title, ``intro`` (HTML), the viewer, the layers' sources and ``extra`` (HTML:
    videos, links to the full-resolution files)."""
    return (f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title>'
            f"<style>{PAGE_STYLE}</style></head><body><h1>{html.escape(title)}</h1>\n{intro}\n"
            + view_fragment(data) + layer_table(data) + extra + view_scripts() + "</body></html>\n")
