"""Self-contained HTML of the demo report: every image and video embedded as a base64 data URI,
the 3D view's scripts inlined (c3f_slam.view.page), nothing to load, so the file opens offline
in any browser. Pure: images and videos come with their bytes, no file is read."""

from __future__ import annotations

import base64
import html

from c3f_demo.report_records import Image, Video

STYLE = """body{font-family:sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;color:#222}
h1{font-size:1.6em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:1.8em}
table{border-collapse:collapse;margin:.6em 0}td,th{border:1px solid #ccc;padding:.25em .6em;text-align:left}
th{background:#f2f2f2}.fail{color:#b00;font-weight:bold}
.note{background:#fff6d6;border-left:4px solid #e0b400;padding:.4em .8em}img{max-width:100%;margin:.3em 0}
figure{display:inline-block;margin:.3em;vertical-align:top}figcaption{font-size:.85em;color:#555}
code{background:#f4f4f4;padding:0 .2em}"""


def esc(x) -> str:
    return html.escape(str(x))


def image(img: Image, caption: str = "", width: int | None = None) -> str:
    """An ``<img>`` with the PNG embedded (a plain note when the file was missing)."""
    if img.png is None:
        return f'<p class="fail">missing image: {esc(img.name)}</p>'
    data = base64.b64encode(img.png).decode("ascii")
    w = f' width="{width}"' if width else ""
    cap = f"<figcaption>{esc(caption)}</figcaption>" if caption else ""
    return f'<figure><img alt="{esc(caption or img.name)}"{w} src="data:image/png;base64,{data}">{cap}</figure>'


def video(v: Video, max_bytes: int) -> str:
    """A ``<video>`` with the MP4 embedded when it is at most ``max_bytes``, else a note with a link
    to it (its path, relative to the report)."""
    from c3f_slam.view.page import video_element

    if v.data is None:
        return f'<p class="fail">missing video: {esc(v.path)}</p>'
    size = len(v.data)
    if size > max_bytes:
        return (f"<p>{esc(v.caption)}: {size / 1e6:.1f} MB, above the report's {max_bytes / 1e6:.0f} MB per video, "
                f'so not embedded: <a href="{esc(v.path)}">{esc(v.path)}</a>, beside the report.</p>')
    data = base64.b64encode(v.data).decode("ascii")
    return video_element(f"data:video/mp4;base64,{data}", v.caption, v.name)


def table(header: list[str], rows: list[list]) -> str:
    head = "".join(f"<th>{esc(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in row) + "</tr>" for row in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def section(sid: str, title: str, body: str) -> str:
    return f'<section id="{sid}"><h2>{esc(title)}</h2>\n{body}\n</section>\n'


def page(title: str, sections: list[str], tail: str = "") -> str:
    """The whole document; ``tail``: HTML after the sections (the 3D view's scripts)."""
    return (f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8"><title>{esc(title)}</title>'
            f"<style>{STYLE}</style></head><body><h1>{esc(title)}</h1>\n" + "".join(sections) + tail
            + "</body></html>\n")
