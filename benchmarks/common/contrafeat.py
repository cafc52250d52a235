"""ContraFeat matching benchmarks (paper table 2): the small CPU model, loading the checkpoints
``benchmarks.protocols.contrafeat_pr`` saves, testing a model per held-out sequence and the report tables.

Recall and precision are fractions in [0, 1] in the metrics and percentages in the tables;
``pixel_radius`` and the near-miss radius are pixels.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path

import torch
import yaml

from benchmarks.common import ROOT
from c3f_models.contrafeat.module import METHODS, ContraFeat
from c3f_models.contrafeat.pairs import GroundTruthSettings
from c3f_models.zoo.evaluate import descriptor_metrics

LABELS = {"sift": "SIFT", "sift_kpf": "SIFT+kpf", "cdf": "CDF", "cdf_kpf": "CDF+kpf"}
SMALL_CONFIG = ROOT / "configs" / "contrafeat" / "small.yaml"  #: the small CPU model, the one place it is written


def small_model_args() -> dict:
    """ContraFeat's init arguments of :data:`SMALL_CONFIG` (only what differs from the code's
    defaults), with no match images (``evaluation.num_visualisations`` 0)."""
    args = yaml.safe_load(SMALL_CONFIG.read_text())["model"]["init_args"]
    return {**args, "evaluation": {**args.get("evaluation", {}), "num_visualisations": 0}}


SMALL_MODEL = small_model_args()
GROUND_TRUTH = asdict(GroundTruthSettings())  #: the ground-truth matching of every ContraFeat (code defaults)


def load_weights(model: ContraFeat, ckpt: Path, option: str = "--checkpoint") -> int:
    """Load a checkpoint ``benchmarks.protocols.contrafeat_pr`` saved into ``model``; returns its step count.

    Exits with one line naming ``option`` and the file when it is missing, holds no
    ``state_dict`` or does not fit the model.
    """
    if not ckpt.is_file():
        raise SystemExit(f"{option}: no such file: {ckpt}")
    saved = torch.load(ckpt, map_location="cpu", weights_only=True)
    if not isinstance(saved, dict) or "state_dict" not in saved:
        raise SystemExit(f"{option}: {ckpt} holds no state_dict (not a ContraFeat checkpoint)")
    try:
        model.load_state_dict(saved["state_dict"])
    except RuntimeError as e:
        raise SystemExit(f"{option}: {ckpt} does not fit the small ContraFeat configuration: "
                         f"{str(e).splitlines()[0]}") from None
    return int(saved.get("global_step", 0))


@dataclass(frozen=True)
class PairSelection:
    """Which frame pairs of a sequence are tested: frame ``gaps``, every ``stride``-th pair of
    each gap, frames resized to ``size`` x ``size`` pixels, at most ``max_batches`` batches of 4
    (None: all)."""

    gaps: list[int]
    stride: int
    size: int
    max_batches: int | None = None

    @classmethod
    def from_args(cls, args) -> PairSelection:
        """From a script's ``--eval-gaps``, ``--eval-stride``, ``--size`` and ``--eval-batches``."""
        return cls(args.eval_gaps, args.eval_stride, args.size, args.eval_batches)


def metrics_per_sequence(model: ContraFeat, data_dir: Path, seqs: list[str], pairs: PairSelection) -> dict[str, dict]:
    """Per held-out sequence in ``data_dir``: the test metrics of ``model`` (``test/...`` keys)."""
    return descriptor_metrics(model, data_dir, seqs, gaps=pairs.gaps, stride=pairs.stride, size=pairs.size,
                              max_batches=pairs.max_batches)


def _percent(x: float | None) -> str:
    return "n/a" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{100 * x:.1f}"


def _recall_precision(rec: float, prec: float) -> str:
    return f"{_percent(rec)}/{_percent(prec)}"


def recall_precision_table(results: dict[str, dict]) -> list[str]:
    """Markdown rows: recall/precision % of each method per sequence, their average, and the
    ground-truth matches per pair."""
    lines = ["| Seq. | " + " | ".join(f"{LABELS[m]} [%]" for m in METHODS) + " | GT matches / pair |",
             "|---|" + "---|" * (len(METHODS) + 1)]
    for name, r in results.items():
        cells = [_recall_precision(r[f"test/{m}_recall"], r[f"test/{m}_precision"]) for m in METHODS]
        lines.append(f"| {name} | " + " | ".join(cells) + f" | {r['test/gt_matches']:.1f} |")
    avg = {k: sum(r[k] for r in results.values()) / len(results) for k in next(iter(results.values()))}
    cells = [_recall_precision(avg[f"test/{m}_recall"], avg[f"test/{m}_precision"]) for m in METHODS]
    lines.append("| **average** | " + " | ".join(f"**{c}**" for c in cells) + f" | {avg['test/gt_matches']:.1f} |")
    return lines


def _mean_where_defined(values: list[float]) -> float:
    """Mean over the sequences where a value is defined (a share needs a wrong match)."""
    values = [v for v in values if not math.isnan(v)]
    return sum(values) / len(values) if values else float("nan")


def wrong_match_table(results: dict[str, dict]) -> list[str]:
    """Where the precision goes, averaged over the sequences (see c3f_slam.matching.match_accuracy).

    A sequence without wrong matches has no shares; it is left out of those averages.
    """
    lines = [("| | precision [%] | precision within 3 x radius [%] | near misses / wrong [%] | "
             "near misses without counterpart / wrong [%] |"), "|---|---|---|---|---|"]
    for m in METHODS:
        avg = {k: _mean_where_defined([r[f"test/{m}_{k}"] for r in results.values()])
               for k in ("precision", "near_precision", "near_miss_share", "no_counterpart_share")}
        lines.append(f"| {LABELS[m]} | {_percent(avg['precision'])} | {_percent(avg['near_precision'])} | "
                     f"{_percent(avg['near_miss_share'])} | {_percent(avg['no_counterpart_share'])} |")
    return lines
