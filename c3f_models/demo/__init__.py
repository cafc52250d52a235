"""The demo: the project's whole pipeline in one command (``python -m c3f_models demo``).

simulate -> train_depth -> train_features -> export -> slam -> evaluate -> report, each stage
running the project's own command lines (:mod:`c3f_models.demo.stages`), all outputs in one
folder, resumable (:mod:`c3f_models.demo.state`), ending in a self-contained ``report.html``.
"""

from c3f_models.demo.config import DemoConfig, demo_config

__all__ = ["DemoConfig", "demo_config"]
