"""What the benchmark scripts share: simulator data (:mod:`.simulate`), report files
(:mod:`.report`) and the ContraFeat evaluation of the matching benchmarks (:mod:`.contrafeat`)."""

from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]  # the repository root
RESULTS = ROOT / "benchmarks" / "results"  # recorded reports, indexed in results/README.md
