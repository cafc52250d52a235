"""``python -m c3f_slam view OUT``: ``OUT/view.html``, ``OUT/rerender.mp4`` and ``OUT/flythrough.mp4``,
then ``OUT/view.json``: the settings used (``settings``: ``view OUT --config OUT/view.json``
replays them), the inputs and what was written.

The page is written after the videos, so it links only the videos that exist. Every file is
written atomically; a run folder is never changed otherwise.
"""

from __future__ import annotations

import html
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import open3d as o3d
from tqdm import tqdm

from c3f_core.atomic import atomic_write_text
from c3f_core.errors import InputError
from c3f_core.settings import tree_as_mapping
from c3f_slam.camera.intrinsics import PinholeCamera
from c3f_slam.io import read_tum
from c3f_slam.io.run_outputs import FrameLog, RunOutputs, write_json
from c3f_slam.view.flythrough import flythrough_frames
from c3f_slam.view.layers import Layer
from c3f_slam.view.page import view_data, view_page
from c3f_slam.view.raycast import MeshScene
from c3f_slam.view.rerender import PoseLookup, RenderClock, rerender_frames
from c3f_slam.view.scene import run_layers
from c3f_slam.view.settings import ViewSettings
from c3f_slam.view.video import write_mp4

PAGE, RERENDER, FLYTHROUGH, RECORD = "view.html", "rerender.mp4", "flythrough.mp4", "view.json"
CAPTIONS = {RERENDER: "input (left) beside the reconstruction rendered from each frame's estimated pose (right), "
                      "unseen wall blue",
            FLYTHROUGH: "the final model seen along the smoothed camera path, unseen wall blue"}


@dataclass
class ViewResult:
    """What :func:`write_view` wrote: files (names in the run folder), page size (bytes), triangles
    on the page, and per video its frames and render time per frame (ms)."""

    files: list[str] = field(default_factory=list)
    page_bytes: int = 0
    triangles: int = 0
    videos: dict[str, dict] = field(default_factory=dict)


def read_summary(out: RunOutputs) -> dict:
    """summary.json of a run folder (an InputError naming it when it is not one)."""
    if not out.summary.is_file():
        raise InputError(f"{out.summary}: not found ({out.root} is not a run folder of `python -m c3f_slam run`)")
    try:
        return json.loads(out.summary.read_text())
    except json.JSONDecodeError as exc:
        raise InputError(f"{out.summary}: not valid JSON ({exc})") from None


def model_mesh(out: RunOutputs) -> o3d.geometry.TriangleMesh | None:
    """The final model of the videos: unseen.ply (unseen wall painted), else mesh.ply; None if neither."""
    for path in (out.unseen_mesh, out.mesh):
        if path.is_file():
            mesh = o3d.io.read_triangle_mesh(str(path))
            if len(mesh.triangles):
                return mesh
    return None


def _input_stream(summary: dict, sequence: str | Path | None):
    """The frames the run read, from ``sequence`` or summary.json's ``sequence``."""
    from c3f_slam.frames.stream import open_stream  # OpenCV

    source = Path(sequence) if sequence is not None else Path(summary.get("sequence") or "")
    if not source.exists() or str(source) in ("", "."):
        raise InputError(f"{source}: the run's input is not there (summary.json sequence); give --sequence "
                         "SEQ_OR_VIDEO, or --no-video for the page alone")
    if "camera" not in summary:
        raise InputError(f"summary.json has no camera to re-render {source} with; --no-video for the page alone")
    frames = summary.get("config", {}).get("frames", {})
    cam = PinholeCamera(**{k: summary["camera"][k] for k in ("width", "height", "fx", "fy", "cx", "cy")})
    lens = _lens_file(summary) if source.is_file() else None  # a video read through its lens model
    stream = open_stream(source, camera=lens or cam, use_depth=False, step=int(frames.get("stride") or 1),
                         max_frames=frames.get("max_frames"))
    return stream, cam


def _lens_file(summary: dict) -> Path | None:
    """The camera.json a video run read its lens from (summary.json ``camera_source`` "file PATH
    (...)"), when it is still there and describes a distorted lens: the frames are then undistorted
    as the run undistorted them. None otherwise (the run's pinhole camera is used)."""
    source = str(summary.get("camera_source") or "")
    if not source.startswith("file ") or "undistort" not in source:
        return None
    path = Path(source[len("file "):].split(" (")[0])
    return path if path.is_file() else None


def write_videos(out: RunOutputs, summary: dict, sequence: str | Path | None, progress: bool,
                 settings: ViewSettings) -> dict[str, dict]:
    """rerender.mp4 and flythrough.mp4 of the run (none without a mesh or a trajectory), encoded
    as ``settings.video`` says, the fly-through as ``settings.flythrough`` says."""
    mesh = model_mesh(out)
    if mesh is None or not out.trajectory.is_file():
        return {}
    stamps, poses = read_tum(out.trajectory)
    stream, cam = _input_stream(summary, sequence)
    ms = MeshScene.of(mesh)
    tissue = None
    if out.tissue_mask.is_file():
        import cv2  # as the stream: only when videos are written

        tissue = cv2.imread(str(out.tissue_mask), cv2.IMREAD_GRAYSCALE) > 127
        tissue = tissue if tissue.shape == (cam.height, cam.width) else None
    done = {}
    jobs = ((RERENDER, len(stream), lambda c: rerender_frames(
                stream, K=cam.K, width=cam.width, height=cam.height, ms=ms, lookup=PoseLookup(stamps, poses), clock=c,
                tissue=tissue, outcomes=FrameLog.read(out.frame_log))),
            (FLYTHROUGH, settings.flythrough.frames, lambda c: flythrough_frames(ms, poses, c, settings.flythrough)))
    for name, total, frames in jobs:
        clock = RenderClock()
        bar = tqdm(frames(clock), total=total, desc=name, unit="frame", disable=not progress, leave=False)
        n = write_mp4(out.root / name, bar, settings.video)
        if n:
            done[name] = {"frames": n, "rendered": clock.frames, "ms_per_frame": clock.ms_per_frame}
    return done


def _intro(summary: dict, run: Path) -> str:
    share = summary.get("unseen_share")
    reg = summary.get("registered_share")
    facts = [f"{summary.get('frames', 'n/a')} frames",
             f"{100 * reg:.1f} % registered" if reg is not None else "",
             f"unseen wall {100 * share:.1f} % (the run's own estimate)" if share is not None else "",
             f"status {summary.get('status', 'n/a')}"]
    links = " · ".join(f'<a href="{n}">{n}</a>' for n in ("mesh.ply", "unseen.ply", "coverage.ply", "summary.json")
                       if (run / n).is_file())
    return (f"<p>Run folder <code>{html.escape(str(run))}</code>: " + ", ".join(f for f in facts if f) + ".</p>"
            f"<p>Full-resolution files (MeshLab, Open3D): {links}</p>")


def _videos_html(videos: dict[str, dict]) -> str:
    from c3f_slam.view.page import video_element

    return "<h2>Videos</h2>" + "".join(video_element(n, f"{n}: {CAPTIONS[n]}", n) for n in videos) if videos else ""


def write_view(run: str | Path, gt: str | Path | None = None, videos: bool = True,
               sequence: str | Path | None = None, settings: ViewSettings | None = None,
               progress: bool = True) -> ViewResult:
    """Write the run folder's view page and (``videos``) its two videos, then the record of the
    ``settings`` used (default the defaults: :class:`ViewSettings`); see the module docstring."""
    settings = settings or ViewSettings()
    out = RunOutputs(run)
    summary = read_summary(out)
    layers: list[Layer] = run_layers(out.root, settings.budget, gt)
    res = ViewResult()
    if videos:
        res.videos = write_videos(out, summary, sequence, progress, settings)
    # --no-video keeps (and links) the videos an earlier view wrote
    linked = dict(res.videos) | {n: {} for n in (RERENDER, FLYTHROUGH) if not videos and (out.root / n).is_file()}
    page = view_page(f"C3Fusion view: {out.root.resolve().name}", _intro(summary, out.root),
                     view_data(layers), _videos_html(linked))
    atomic_write_text(out.root / PAGE, page)
    res.files = [PAGE, *res.videos, RECORD]
    res.page_bytes = len(page.encode())
    res.triangles = int(np.sum([lay.triangles for lay in layers]))
    write_json(out.root / RECORD, {"settings": tree_as_mapping(settings), "gt": None if gt is None else str(gt),
                                   "sequence": None if sequence is None else str(sequence), "with_videos": videos,
                                   "videos": res.videos, "files": res.files, "page_bytes": res.page_bytes,
                                   "triangles": res.triangles})
    return res
