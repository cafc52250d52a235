"""Match visualisation: two frames side by side; correct matches green, near misses yellow,
other wrong ones red (near misses: :func:`c3f_slam.matching.match_accuracy.near_misses`)."""

from __future__ import annotations

import cv2
import numpy as np

GREEN = (40, 220, 40)
RED = (230, 40, 40)
YELLOW = (240, 210, 30)


def draw_matches(
    image_i: np.ndarray,
    image_j: np.ndarray,
    kp_i: np.ndarray,
    kp_j: np.ndarray,
    matches: np.ndarray,
    *,
    correct: np.ndarray | None = None,
    max_lines: int | None = 200,
    scale: int = 1,
    near: np.ndarray | None = None,
) -> np.ndarray:
    """(H*s, 2*W*s, 3) uint8 RGB: frame i left, frame j right, one line per match.

    Args:
        image_i, image_j: (H, W, 3) uint8 RGB frames of the same size.
        kp_i, kp_j: (N, 2) pixel coordinates (u, v).
        matches: (M, 2) index pairs.
        correct: optional (M,) bool (green = True, red = False; all green when None).
        max_lines: draw at most this many matches (evenly spaced), None = all.
        scale: integer upscaling of the canvas, for small frames.
        near: optional (M,) bool: wrong matches drawn yellow instead of red (near misses).
    """
    h, w = image_i.shape[:2]
    canvas = np.concatenate([image_i, image_j], axis=1).astype(np.uint8)
    if scale > 1:
        canvas = cv2.resize(canvas, (2 * w * scale, h * scale), interpolation=cv2.INTER_NEAREST)
    canvas = np.ascontiguousarray(canvas)
    matches = np.asarray(matches, dtype=np.int64).reshape(-1, 2)
    ok = np.ones(len(matches), bool) if correct is None else np.asarray(correct, bool)
    close = np.zeros(len(matches), bool) if near is None else np.asarray(near, bool) & ~ok
    sel = np.arange(len(matches))
    if max_lines is not None and len(sel) > max_lines:
        sel = np.linspace(0, len(sel) - 1, max_lines).round().astype(np.int64)
    # red first, then yellow, so that correct (green) lines stay on top
    rank = 2 * ok.astype(np.int64) + close
    for k in sel[np.argsort(rank[sel], kind="stable")]:
        a, b = matches[k]
        p = (np.asarray(kp_i[a], float) + 0.5) * scale - 0.5
        q = (np.asarray(kp_j[b], float) + 0.5) * scale - 0.5
        q[0] += w * scale
        color = GREEN if ok[k] else YELLOW if close[k] else RED
        pi, qi = tuple(int(round(x)) for x in p), tuple(int(round(x)) for x in q)
        cv2.line(canvas, pi, qi, color, 1, cv2.LINE_AA)
        cv2.circle(canvas, pi, 2, color, -1, cv2.LINE_AA)
        cv2.circle(canvas, qi, 2, color, -1, cv2.LINE_AA)
    return canvas
