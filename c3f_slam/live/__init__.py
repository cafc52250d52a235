"""``python -m c3f_slam live SOURCE``: the run of ``run``, shown while the video plays.

The same pipeline as ``run`` takes the frames of a video file (at its own frame rate), a
sequence folder or a capture device; when processing falls behind, the newest frame wins and
the others are dropped (:mod:`.source`). After each frame the unseen-wall estimate is updated
incrementally (:mod:`c3f_slam.coverage.incremental`), a segment the scope leaves with more
unseen wall than the threshold raises an alert (:mod:`.alerts`), and what a page shows is
published to a thread-safe store (:mod:`.state`) that a small HTTP server on the loopback
address serves (:mod:`.server`, the page: ``page.html``, ``live.js``). docs/live.md
"""
