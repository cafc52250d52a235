"""The demo: the project's whole pipeline in one command (``python -m c3f_demo``).

simulate -> train_depth -> ttt_depth -> train_features -> export -> slam -> evaluate -> report,
each stage running the project's own command lines (:mod:`c3f_demo.stages`), all outputs in one
folder, resumable (:mod:`c3f_demo.state`), ending in a self-contained ``report.html``. On a
user's own video (``--video FILE``): ingest -> ... -> slam -> view -> report, with no ground
truth (:mod:`c3f_demo.video`).
"""

from c3f_demo.config import DemoConfig, demo_config, video_config

__all__ = ["DemoConfig", "demo_config", "video_config"]
