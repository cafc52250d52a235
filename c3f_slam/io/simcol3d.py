"""SimCol3D challenge (SimCol-to-3D, MICCAI 2022): its evaluation protocol and submission files.

Everything here follows the organisers' public code, repository ``anitarau/simcol``:
``evaluation/eval_synthetic_depth.py`` (commit 1db4b6d), ``evaluation/eval_synthetic_pose.py``
(commit de2fb47) and the submission templates ``docker_templates/SimCol3D-task1-depth-docker/src/``
and ``docker_templates/SimCol3D-task2_pose-docker/src/`` (``main.py``, ``add_your_code_here.py``).
The code below is written from these facts, not copied.

Depth (task 1, ``eval_synthetic_depth.py``, depth template):

- Files: ``<trajectory>/depth/FrameBuffer_NNNN.npy``, one per frame, named as the RGB frame
  (601 per trajectory of SyntheticColon_I, 1201 of II and III; the script checks the count).
  Each holds a float16 array of shape (475, 475) (both asserted) in [0, 1], where 1 = 20 cm.
  Values outside [0, 1] draw a warning and are clipped to [0, 1]; nothing marks "no depth".
- Ground truth: ``Depth_NNNN.png`` read as ``value / 255 / 256`` (so 65,280 = 1 = 20 cm; the
  saturated 65,535 counts as 20.08 cm: the script has no mask).
- Scale: ONE factor per trajectory, least squares on the per-frame MEANS over all pixels:
  ``s = sum_i(mean(p_i) * mean(g_i)) / sum_i(mean(p_i) ** 2)`` (p: clipped prediction, g: gt).
- Per frame, on every pixel, with ``d = 20 * s * p - 20 * g`` (cm): L1 = mean(|d|) cm;
  relative = median(|d| / (20 * g + 1e-4)) * 100 (%); RMSE = sqrt(mean(d ** 2)) cm.
- Per trajectory: the mean over frames of each (the relative error printed as "Median relative
  error in %" is the mean of the per-frame medians). The script prints each trajectory and no
  average over trajectories; :func:`mean_over_trajectories` is the plain mean of those.

Camera pose (task 2, ``eval_synthetic_pose.py``, pose template):

- Files: ``<trajectory>/pose/FrameBuffer_NNNN_to_FrameBuffer_MMMM.txt`` for every consecutive
  pair (MMMM = NNNN + 1: 600 / 1200 files, counted; only the forward pairs); one line of 16
  numbers, space separated, the row-major 4x4 ``[R t; 0 0 0 1]`` (``str`` of each float). Only
  the first line is read; elements of R outside [-1, 1] and a last row other than 0 0 0 1 draw
  warnings. The pose is "the position of camera 2's origin in camera 1's frame":
  ``inv(P_1) @ P_2`` of camera-to-world poses.
- Frame of the poses: the ground truth is read from ``SavedPosition_X.txt`` (cm) and
  ``SavedRotationQuaternion_X.txt`` (qx qy qz qw, ``scipy`` order), Unity's left-handed frame,
  and converted with ``TM @ P @ TM``, TM = diag(1, -1, 1, 1). That is exactly the project's
  conversion (:mod:`datamodules.formats.unity`, which also turns cm into metres): a relative
  pose in the submission is our relative pose with its translation in centimetres (x right,
  y down, z forward). No further flip.
- Scale: ONE factor per trajectory, least squares on the relative translations:
  ``s = sum(t_gt . t_pred) / sum(|t_pred| ** 2)`` over all pairs.
- Both relative-pose lists are chained from the identity (``T_0 = I``, ``T_k+1 = T_k @ rel_k``);
  the predicted chain's translations are multiplied by s. No rotation or origin alignment.
- ATE = median over frames of ``|t_gt_k - t_pred_k|``; per pair, ``E = inv(Q) @ P`` (Q, P: gt
  and scaled predicted relative poses recomputed from the chains), RTE = median of ``|t_E|``,
  ROT = median of ``arccos((trace(R_E) - 1) / 2)`` in degrees. ATE and RTE are in the ground
  truth's unit, centimetres. (The script clips the trace to [-3, 3], which leaves NaN where
  rounding puts it above 3; here the cosine is clipped to [-1, 1].)

In this module depths and translations are metres and poses camera-to-world 4x4 in the
project's convention (OpenCV camera: x right, y down, z forward); reported errors carry their
unit in their name (``l1_cm``, ``rot_deg``).
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

import numpy as np

from c3f_core.atomic import atomic_write, atomic_write_text
from c3f_core.errors import InputError
from c3f_slam.geometry import axis_angle_to_matrix, invert_pose, make_pose, matrix_to_axis_angle, relative_pose

DEPTH_SIZE = 475  #: submitted depth maps are DEPTH_SIZE x DEPTH_SIZE
DEPTH_RANGE_M = 0.20  #: a depth value of 1 in the challenge's files is 20 cm
GT_DEPTH_DIVISOR = 255.0 * 256.0  #: ground-truth PNG value / GT_DEPTH_DIVISOR = depth in units of 20 cm
REL_EPS_CM = 1e-4  #: added to the ground truth (cm) in the relative depth error's denominator
CM_PER_M = 100.0
COUNT_KEYS = ("frames", "pairs")  #: summed, not averaged, by mean_over_trajectories
_POSE_FILE = re.compile(r"^FrameBuffer_(\d+)_to_FrameBuffer_(\d+)\.txt$")


def frame_name(number: int) -> str:
    """``FrameBuffer_NNNN``: SimCol3D's name of frame ``number``."""
    return f"FrameBuffer_{number:04d}"


def depth_file_name(number: int) -> str:
    """Name of the depth prediction of frame ``number`` (``FrameBuffer_NNNN.npy``)."""
    return f"{frame_name(number)}.npy"


def pose_file_name(a: int, b: int) -> str:
    """Name of the relative pose from frame ``a`` to frame ``b`` (``FrameBuffer_a_to_FrameBuffer_b.txt``)."""
    return f"{frame_name(a)}_to_{frame_name(b)}.txt"


# ---------------------------------------------------------------------- depth files


def _unit_depth(depth_m: np.ndarray) -> np.ndarray:
    """Metres -> the challenge's unit (1 = 20 cm), float64, clipped to [0, 1] as the official
    script clips submissions; NaN and -inf become 0, +inf becomes 1."""
    d = np.asarray(depth_m, dtype=np.float64) / DEPTH_RANGE_M
    return np.clip(np.nan_to_num(d, nan=0.0, posinf=1.0, neginf=0.0), 0.0, 1.0)


def submission_depth(depth_m: np.ndarray) -> np.ndarray:
    """(H, W) depth in metres -> the submitted array: float16 (475, 475) in [0, 1] of 20 cm.

    Another size is resized to 475 x 475 (each axis on its own, bilinear, OpenCV's pixel-centre
    convention) after the non-finite values are replaced (NaN: 0, +inf: 20 cm); values beyond
    [0, 20 cm] are clipped, as the official script would. float16 keeps about 0.01 cm near 20 cm.
    """
    d = np.asarray(depth_m)
    if d.ndim != 2 or min(d.shape) < 1:
        raise InputError(f"depth: expected an (H, W) array, got shape {d.shape}")
    unit = _unit_depth(d)
    if unit.shape != (DEPTH_SIZE, DEPTH_SIZE):
        import cv2

        unit = cv2.resize(unit, (DEPTH_SIZE, DEPTH_SIZE), interpolation=cv2.INTER_LINEAR)
    return np.clip(unit, 0.0, 1.0).astype(np.float16)


def write_depth_prediction(path: str | Path, depth_m: np.ndarray) -> Path:
    """Write one frame's depth (metres) as the challenge's ``.npy`` (:func:`submission_depth`);
    ``.npy`` is appended to a name without it (as ``np.save`` does). Returns the path."""
    path = Path(path)
    if path.suffix != ".npy":
        path = path.with_name(path.name + ".npy")
    arr = submission_depth(depth_m)
    with atomic_write(path) as tmp:
        np.save(tmp, arr)
    return path


def read_depth_prediction(path: str | Path) -> np.ndarray:
    """A submitted depth file -> (475, 475) float32 metres, clipped to [0, 20 cm] as the official
    script reads it; a wrong shape or dtype is an InputError (the script asserts both)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: depth prediction not found")
    try:
        arr = np.load(path, allow_pickle=False)
    except (ValueError, OSError) as exc:
        raise InputError(f"{path}: not a NumPy .npy file ({exc})") from None
    if arr.shape != (DEPTH_SIZE, DEPTH_SIZE) or arr.dtype != np.float16:
        raise InputError(f"{path}: expected float16 of shape ({DEPTH_SIZE}, {DEPTH_SIZE}), "
                         f"got {arr.dtype} of shape {arr.shape}")
    return (np.clip(arr.astype(np.float32), 0.0, 1.0) * np.float32(DEPTH_RANGE_M)).astype(np.float32)


def read_gt_depth_png(path: str | Path) -> np.ndarray:
    """A SimCol3D ``Depth_NNNN.png`` read as the official script reads it, in metres:
    ``value / 255 / 256 * 20 cm`` (no mask: the saturated 65,535 is 20.08 cm, not "no depth"
    as the project's loader reads it)."""
    import cv2

    path = Path(path)
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if raw is None:
        raise InputError(f"{path}: depth image not found or does not decode")
    if raw.ndim != 2 or raw.dtype != np.uint16:
        raise InputError(f"{path}: expected a single-channel 16-bit PNG, got {raw.dtype} with shape {raw.shape}")
    return raw.astype(np.float64) / GT_DEPTH_DIVISOR * DEPTH_RANGE_M


# ---------------------------------------------------------------------- depth metrics


def _depth_pairs(preds: Sequence[np.ndarray], gts: Sequence[np.ndarray]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Checked (prediction, ground truth) pairs in the challenge's unit (1 = 20 cm)."""
    if len(preds) != len(gts):
        raise InputError(f"preds: {len(preds)} depth maps for {len(gts)} ground-truth maps")
    if len(preds) == 0:
        raise InputError("preds: no depth maps")
    pairs = []
    for i, (p, g) in enumerate(zip(preds, gts)):
        p, g = np.asarray(p), np.asarray(g, dtype=np.float64)
        if p.shape != g.shape or p.ndim != 2:
            raise InputError(f"preds[{i}]: shape {p.shape} does not match gts[{i}] {g.shape} (two (H, W) maps)")
        if not np.all(np.isfinite(g)):
            raise InputError(f"gts[{i}]: non-finite ground-truth depth")
        pairs.append((_unit_depth(p), g / DEPTH_RANGE_M))
    return pairs


def depth_metrics_per_trajectory(preds: Sequence[np.ndarray], gts: Sequence[np.ndarray]) -> dict[str, float]:
    """The official depth metrics of one trajectory (module docstring).

    ``preds`` / ``gts``: the trajectory's depth maps in metres, (H, W) each, paired by position.
    Predictions are clipped to [0, 20 cm] (NaN: 0) as the challenge's files are; no pixel is
    masked. For the official numbers pass the ground truth as the script reads it
    (:func:`read_gt_depth_png`). Returns ``scale`` (the least-squares factor on the per-frame
    means, unitless), ``l1_cm``, ``median_rel_pct`` (mean over frames of the per-frame median
    relative error, %), ``rmse_cm`` (both means over frames) and ``frames``.
    """
    pairs = _depth_pairs(preds, gts)
    mp = np.array([p.mean() for p, _ in pairs])
    mg = np.array([g.mean() for _, g in pairs])
    denom = float(np.sum(mp * mp))
    if denom <= 0:
        raise InputError("preds: every predicted depth is 0 (after clipping to [0, 20 cm]); no scale can be fitted")
    scale = float(np.sum(mp * mg)) / denom
    l1, rel, rmse = [], [], []
    for p, g in pairs:
        diff = 20.0 * scale * p - 20.0 * g
        l1.append(np.mean(np.abs(diff)))
        rel.append(np.median(np.abs(diff) / (20.0 * g + REL_EPS_CM)) * 100.0)
        rmse.append(np.sqrt(np.mean(diff * diff)))
    return {"scale": scale, "l1_cm": float(np.mean(l1)), "median_rel_pct": float(np.mean(rel)),
            "rmse_cm": float(np.mean(rmse)), "frames": len(pairs)}


def mean_over_trajectories(results: Iterable[Mapping[str, float]]) -> dict[str, float]:
    """Plain mean over trajectories of each metric the per-trajectory results share (depth or
    pose dicts of this module); ``frames`` / ``pairs`` are summed; ``trajectories`` counts them.
    (The official scripts print one result per trajectory and no average.)"""
    results = list(results)
    if not results:
        raise InputError("results: no trajectories to average")
    keys = [k for k in results[0] if all(k in r for r in results[1:])]
    out: dict[str, float] = {}
    for k in keys:
        vals = [r[k] for r in results]
        out[k] = int(sum(vals)) if k in COUNT_KEYS else float(np.mean(vals))
    out["trajectories"] = len(results)
    return out


# ---------------------------------------------------------------------- poses


def _check_poses(poses: np.ndarray, what: str, min_len: int = 2) -> np.ndarray:
    P = np.asarray(poses, dtype=np.float64)
    if P.ndim != 3 or P.shape[1:] != (4, 4) or len(P) < min_len:
        raise InputError(f"{what}: expected at least {min_len} 4x4 poses (N, 4, 4), got shape {P.shape}")
    if not np.all(np.isfinite(P)):
        raise InputError(f"{what}: non-finite pose values")
    return P


def relative_poses(poses: np.ndarray) -> np.ndarray:
    """(N, 4, 4) camera-to-world poses -> (N - 1, 4, 4) ``inv(T_i) @ T_i+1`` (frame i+1 in frame i),
    the challenge's relative pose, in the poses' units."""
    P = _check_poses(poses, "poses")
    return relative_pose(P[:-1], P[1:])


def chain_relative_poses(rel: np.ndarray) -> np.ndarray:
    """(M, 4, 4) relative poses -> (M + 1, 4, 4) camera-to-world poses from the identity, as the
    official scripts rebuild trajectories (``T_0 = I``, ``T_k+1 = T_k @ rel_k``)."""
    R = _check_poses(rel, "relative poses", 1)
    out = [np.eye(4)]
    for T in R:
        out.append(out[-1] @ T)
    return np.asarray(out)


def pose_scale(gt_rel: np.ndarray, pred_rel: np.ndarray) -> float:
    """Least-squares factor on the relative translations that brings ``pred_rel`` to ``gt_rel``:
    ``sum(t_gt . t_pred) / sum(|t_pred|^2)`` (units of gt per unit of pred)."""
    tp, tg = pred_rel[:, :3, 3], gt_rel[:, :3, 3]
    denom = float(np.sum(tp * tp))
    if denom <= 0:
        raise InputError("pred: every predicted relative translation is zero; no scale can be fitted")
    return float(np.sum(tg * tp)) / denom


def pose_metrics_from_relative(pred_rel: np.ndarray, gt_rel: np.ndarray) -> dict[str, float]:
    """The official pose metrics of one trajectory from its relative poses (module docstring).

    ``pred_rel`` / ``gt_rel``: (M, 4, 4) relative poses (:func:`relative_poses`), translations in
    metres. Returns ``scale`` (pred -> gt), ``ate_cm`` and ``rte_cm`` (medians, cm), ``rot_deg``
    (median relative rotation error, degrees) and ``pairs``.
    """
    pred_rel = _check_poses(pred_rel, "pred", 1)
    gt_rel = _check_poses(gt_rel, "gt", 1)
    if len(pred_rel) != len(gt_rel):
        raise InputError(f"pred: {len(pred_rel)} relative poses for {len(gt_rel)} ground-truth ones")
    scale = pose_scale(gt_rel, pred_rel)
    gt, pred = chain_relative_poses(gt_rel), chain_relative_poses(pred_rel)
    pred[:, :3, 3] *= scale
    ate = np.linalg.norm(gt[:, :3, 3] - pred[:, :3, 3], axis=1)
    E = invert_pose(relative_pose(gt[:-1], gt[1:])) @ relative_pose(pred[:-1], pred[1:])
    rte = np.linalg.norm(E[:, :3, 3], axis=1)
    cos = np.clip((np.trace(E[:, :3, :3], axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    return {"scale": scale, "ate_cm": float(np.median(ate)) * CM_PER_M, "rte_cm": float(np.median(rte)) * CM_PER_M,
            "rot_deg": float(np.degrees(np.median(np.arccos(cos)))), "pairs": len(E)}


def pose_metrics_per_trajectory(pred_poses: np.ndarray, gt_poses: np.ndarray) -> dict[str, float]:
    """The official pose metrics of one trajectory from (N, 4, 4) camera-to-world poses in metres
    (the same N frames, paired by position; any world frame, any scale for ``pred_poses``);
    see :func:`pose_metrics_from_relative`."""
    return pose_metrics_from_relative(relative_poses(pred_poses), relative_poses(gt_poses))


# ---------------------------------------------------------------------- pose files


def write_relative_poses(folder: str | Path, poses: np.ndarray, numbers: Sequence[int] | None = None) -> list[Path]:
    """Write the challenge's pose files of a trajectory into ``folder`` (its ``pose/``).

    ``poses``: (N, 4, 4) camera-to-world, metres, the project's convention (as the SimCol3D
    loader reads the release); ``numbers``: the frames' SimCol3D numbers (default 0..N-1). One
    file per consecutive pair, ``FrameBuffer_a_to_FrameBuffer_b.txt``: the 16 numbers of
    ``inv(T_a) @ T_b`` row-major on one line, translation in cm, last row exactly 0 0 0 1.
    """
    P = _check_poses(poses, "poses")
    numbers = list(range(len(P))) if numbers is None else [int(n) for n in numbers]
    if len(numbers) != len(P):
        raise InputError(f"numbers: {len(numbers)} frame numbers for {len(P)} poses")
    folder = Path(folder)
    written = []
    for k, T in enumerate(relative_poses(P)):
        T = T.copy()
        T[:3, 3] *= CM_PER_M
        T[3] = (0.0, 0.0, 0.0, 1.0)
        path = folder / pose_file_name(numbers[k], numbers[k + 1])
        atomic_write_text(path, " ".join(str(float(v)) for v in T.ravel()) + "\n")
        written.append(path)
    return written


def read_pose_file(path: str | Path) -> np.ndarray:
    """One pose file -> 4x4 relative pose, translation in metres (the first line only, as the
    official script reads it)."""
    path = Path(path)
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError):
        raise InputError(f"{path}: pose file not found or not text") from None
    try:
        vals = [float(x) for x in lines[0].split()] if lines else []
    except ValueError:
        raise InputError(f"{path}: not a number on the first line") from None
    if len(vals) != 16 or not np.all(np.isfinite(vals)):
        raise InputError(f"{path}: expected 16 finite numbers on the first line, got {len(vals)}")
    T = np.asarray(vals).reshape(4, 4)
    T[:3, 3] /= CM_PER_M
    return T


def read_relative_poses(folder: str | Path) -> tuple[list[tuple[int, int]], np.ndarray]:
    """A trajectory's ``pose/`` folder -> ([(a, b) frame numbers], (M, 4, 4) relative poses,
    translations in metres), in the official script's order (sorted file names)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"{folder}: pose folder not found")
    files = sorted(p for p in folder.iterdir() if p.name.startswith("FrameBuffer") and p.suffix == ".txt")
    if not files:
        raise InputError(f"{folder}: no FrameBuffer_*_to_FrameBuffer_*.txt pose files")
    pairs = []
    for p in files:
        m = _POSE_FILE.match(p.name)
        if m is None:
            raise InputError(f"{p}: not named FrameBuffer_NNNN_to_FrameBuffer_MMMM.txt")
        pairs.append((int(m.group(1)), int(m.group(2))))
    return pairs, np.asarray([read_pose_file(p) for p in files])


# ---------------------------------------------------------------------- a sequence -> submission


def frame_numbers(names: Sequence[str]) -> list[int]:
    """SimCol3D numbers of frames named ``names`` (file stems): the numbers in the names when
    every name is a distinct number (as ``datamodules convert`` writes them), else 0..N-1."""
    if all(n.isdigit() for n in names) and len({int(n) for n in names}) == len(names):
        return [int(n) for n in names]
    return list(range(len(names)))


def _interpolate(Ta: np.ndarray, Tb: np.ndarray, alpha: float) -> np.ndarray:
    """Pose ``alpha`` of the way from ``Ta`` to ``Tb`` (rotation on the geodesic, translation linear)."""
    dR = axis_angle_to_matrix(alpha * matrix_to_axis_angle(Ta[:3, :3].T @ Tb[:3, :3]))
    return make_pose(Ta[:3, :3] @ dR, (1 - alpha) * Ta[:3, 3] + alpha * Tb[:3, 3])


def poses_for_frames(stamps: np.ndarray, poses: np.ndarray, frame_stamps: np.ndarray,
                     what: str = "trajectory") -> tuple[np.ndarray, int]:
    """A pose for every frame of a sequence from a trajectory that may miss some (``c3f_slam run``
    writes registered frames only): frames are matched by timestamp (within 0.02 s); a frame
    between two matched ones is interpolated, one before the first or after the last takes
    that pose. Returns ((N, 4, 4) poses, number of frames filled)."""
    from c3f_slam.evaluation.trajectory import associate

    ie, ig = associate(stamps, frame_stamps)
    if len(ie) == 0:
        raise InputError(f"{what}: no pose has the timestamp of a frame of the sequence")
    known = dict(zip(ig.tolist(), np.asarray(poses)[ie]))
    idx = np.array(sorted(known))
    out = []
    for k in range(len(frame_stamps)):
        if k in known:
            out.append(known[k])
            continue
        j = np.searchsorted(idx, k)
        if j == 0 or j == len(idx):
            out.append(known[int(idx[min(j, len(idx) - 1)])])
        else:
            a, b = int(idx[j - 1]), int(idx[j])
            out.append(_interpolate(known[a], known[b], (k - a) / (b - a)))
    return np.asarray(out), len(frame_stamps) - len(known)


def write_submission(sequence: str | Path, out: str | Path, depth_model: str | None = None, *, threads: int = 2,
                     depth_scale: float | None = None, trajectory: str | Path | None = None,
                     progress: bool = True) -> dict:
    """Write the submission files of one sequence (project layout) into ``out``:
    ``out/depth/FrameBuffer_NNNN.npy`` for every frame from ``depth_model`` (a DepthNet ONNX
    export or ``zoo:NAME``; depth times ``depth_scale``, default the model's ``metric_scale``,
    else 1, as ``c3f_slam run`` does) and, with ``trajectory`` (TUM, camera-to-world, metres),
    ``out/pose/FrameBuffer_NNNN_to_FrameBuffer_MMMM.txt`` for every consecutive pair. Returns
    counts: ``frames``, ``depth_files``, ``pose_files``, ``filled_poses``, ``depth_scale``."""
    from c3f_slam.frames.stream import FrameStream

    if depth_model is None and trajectory is None:
        raise InputError("nothing to write: give --depth-model and/or --trajectory")
    stream = FrameStream(sequence, use_depth=False)
    seq = stream.sequence
    if seq is None:
        raise InputError(f"{sequence}: not a sequence folder (rgb/, camera.json)")
    numbers = frame_numbers(seq.frame_names)
    res: dict = {"frames": len(seq), "depth_files": 0, "pose_files": 0, "filled_poses": 0, "depth_scale": None}
    if trajectory is not None:  # before the depth maps: a bad trajectory fails at once
        from c3f_slam.io.tum import read_tum

        stamps, poses = read_tum(trajectory)
        frame_stamps = seq.timestamps if seq.timestamps is not None else np.arange(len(seq), dtype=np.float64)
        full, res["filled_poses"] = poses_for_frames(stamps, poses, frame_stamps, str(trajectory))
        if len(full) < 2:
            raise InputError(f"{sequence}: one frame, no relative pose to write")
        res["pose_files"] = len(write_relative_poses(Path(out) / "pose", full, numbers))
    if depth_model is not None:
        res["depth_files"], res["depth_scale"] = _write_depths(
            stream, numbers=numbers, folder=Path(out) / "depth", depth_model=depth_model, threads=threads,
            depth_scale=depth_scale, progress=progress)
    return res


def _write_depths(stream, *, numbers: list[int], folder: Path, depth_model: str, threads: int,
                  depth_scale: float | None, progress: bool) -> tuple[int, float]:
    """Predict and write the depth of every frame of ``stream``; returns (files, factor applied)."""
    from tqdm import tqdm

    from c3f_slam.models.nets import DepthModel
    from c3f_slam.pipeline.frontend import ModelDepth

    if threads < 1:
        raise InputError(f"--threads must be >= 1, got {threads}")
    depth = ModelDepth(DepthModel(depth_model, threads, "--depth-model"), stream.camera, depth_scale)
    n = 0
    for frame in tqdm(stream, total=len(stream), desc="depth", unit="frame", disable=not progress, leave=False):
        if frame.rgb is None:
            raise InputError(f"frame {frame.index}: {frame.error}")
        write_depth_prediction(folder / depth_file_name(numbers[frame.index]), depth.depth(frame))
        n += 1
    return n, depth.scale
