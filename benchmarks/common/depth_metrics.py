"""The seven depth metrics of the DepthNet benchmarks (docs/design.md, Depth metrics: per-image
median scaling) as the test step logs them, and their table cells: Sq Rel and RMSE in centimetres, as the paper's
table prints them, the others unitless."""

from __future__ import annotations

METRICS = ("abs_rel", "sq_rel", "rmse", "rmse_log", "a1", "a2", "a3")
IN_CM = {"sq_rel": 100.0, "rmse": 100.0}  # metres -> cm for the table (Sq Rel has units of depth)
HEADER = "AbsRel | SqRel (cm) | RMSE (cm) | RMSElog | δ1 | δ2 | δ3"


def logged_test_metrics(callback_metrics: dict) -> dict[str, float]:
    """The metrics and ``depth_cv`` (std / mean of the predicted depth) from a trainer's
    ``callback_metrics`` after ``test`` (lengths in metres)."""
    out = {k: float(callback_metrics[f"test/{k}"]) for k in METRICS}
    out["depth_cv"] = float(callback_metrics["test/depth_cv"])
    return out


def metric_cells(m: dict[str, float]) -> str:
    """The seven metrics of ``m`` as Markdown cells (Sq Rel and RMSE in cm), 4 decimals."""
    return " | ".join(f"{m[k] * IN_CM.get(k, 1.0):.4f}" for k in METRICS)
