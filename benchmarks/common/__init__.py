"""What the benchmark scripts share: simulator data (:mod:`.simulate`), report files
(:mod:`.report`: Markdown, and JSON beside a protocol's) and the ContraFeat evaluation of the
matching benchmarks (:mod:`.contrafeat`)."""

from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]  # the repository root
RESULTS = ROOT / "benchmarks" / "results"  # recorded reports, indexed in results/README.md
WORK = ROOT / "runs" / "bench"  # the protocols' sequences and runs (git-ignored), WORK/NAME for each (--work)
#: a study's report (git-ignored): a study is an investigation, its findings go into a dated lab note
#: (docs/lab_notes/), not into RESULTS, which holds one current result per protocol
STUDIES = WORK / "studies"
