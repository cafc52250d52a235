"""The runtime's former tuning flags (aliases of ``--set`` for one release) are gone: each is one
``error: --FLAG was removed: use --set ...`` line, exit status 2, and the ``--set`` it names
gives the settings the flag used to."""

from __future__ import annotations

import pytest
import yaml

from c3f_slam.cli.inputs import settings_from_args
from c3f_slam.cli.main import _parser, main
from c3f_slam.cli.settings_options import REMOVED, removed_message
from c3f_slam.config import PAPER_RULES, config_from_dict, preset

#: every former alias (the --no-X of a switch too)
FORMER = ("--baseline", "--stride", "--max-frames", "--no-mesh", "--no-coverage", "--coverage-segment",
          "--min-correspondences", "--min-overlap", "--max-keypoints", "--ratio", "--max-keyframe-candidates",
          "--max-loop-edges-per-keyframe", "--reuse-keyframes", "--no-reuse-keyframes", "--dense-fallback",
          "--no-dense-fallback", "--dense-refine", "--no-dense-refine", "--guided-matching", "--no-guided-matching",
          "--component-min-frames", "--blas-threads")

RUN = ["run", "SEQ", "--out", "OUT"]


def _removed_line(argv: list[str], capsys) -> str:
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_every_former_alias_is_listed():
    assert sorted(usage.split()[0] for usage in REMOVED) == sorted(FORMER)


@pytest.mark.parametrize("usage", list(REMOVED))
def test_removed_flag_is_one_line_naming_its_replacement(usage, capsys):
    flag, _, value = usage.partition(" ")
    given = [flag] if not value else [flag, value if value.islower() else "1"]  # "--baseline odometry" as is
    line = _removed_line([*RUN, *given], capsys)
    assert line == f"error: {removed_message(usage)} (see python -m c3f_slam run --help)"
    assert line.startswith(f"error: {usage} was removed: use --set ")
    if value:  # the flag alone, without its value, says the same
        assert _removed_line([*RUN, flag], capsys) == line


def test_batch_says_the_same(capsys):
    line = _removed_line(["batch", "DATA", "--out", "OUT", "--no-mesh"], capsys)
    assert line == "error: --no-mesh was removed: use --set fusion.enabled=false (see python -m c3f_slam batch --help)"


SAME = [
    # the former flag, what its line names, the --set items for that value, what the flag used to set
    (["--no-mesh"], "--set fusion.enabled=false", ["fusion.enabled=false"], {"fusion": {"enabled": False}}),
    (["--min-correspondences", "15"], "--set fragments.min_correspondences=N", ["fragments.min_correspondences=15"],
     {"fragments": {"min_correspondences": 15}}),
    (["--ratio", "0"], "for --ratio 0, --set frontend.ratio=none", ["frontend.ratio=none"],
     {"frontend": {"ratio": None}}),
    (["--max-keyframe-candidates", "0"], "for --max-keyframe-candidates 0 (the paper's rules), --set ",
     ["candidates.max_candidates=none", "keyframes.max_loop_edges=none", "keyframes.reuse=false",
      "optimization.growth=none", "optimization.max_nodes=none", "optimization.final_nodes=none"], PAPER_RULES),
    (["--no-reuse-keyframes"], "--set keyframes.reuse=false", ["keyframes.reuse=false"],
     {"keyframes": {"reuse": False}}),
]


@pytest.mark.parametrize("old, named, sets, used_to", SAME, ids=[" ".join(c[0]) for c in SAME])
def test_replacement_gives_what_the_flag_gave(old, named, sets, used_to, capsys):
    line = _removed_line([*RUN, *old], capsys)
    assert named in line and all(f"--set {item.partition('=')[0]}=" in line for item in sets), line
    argv = [*RUN, *(x for item in sets for x in ("--set", item))]
    cfg = settings_from_args(_parser().parse_args(argv))[0]
    assert cfg == preset("colon", **used_to) != preset("colon")
    assert main([*argv, "--print-config"]) == 0  # and --print-config shows that tree
    assert config_from_dict(yaml.safe_load(capsys.readouterr().out)) == cfg
