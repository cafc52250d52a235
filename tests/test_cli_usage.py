"""Usage errors of every command line: one ``error: ...`` line on stderr, exit status 2."""

import pytest

from c3f_models.cli import main as models_main
from c3f_slam.cli.main import main as slam_main
from datamodules.__main__ import main as data_main
from datamodules.synthetic.__main__ import main as sim_main

CASES = [
    (slam_main, ["run"], "the following arguments are required: sequence, --out"),
    (slam_main, ["bogus"], "invalid choice: 'bogus'"),
    (slam_main, ["run", "seq", "--out", "o", "--set"], "argument --set: expected one argument"),
    (slam_main, ["evaluate", "out"], "the following arguments are required: --gt"),
    (slam_main, ["inspect"], "the following arguments are required: model"),
    (data_main, ["convert", "nope", "src", "--out", "o"], "argument dataset: invalid choice: 'nope'"),
    (data_main, ["list"], "the following arguments are required: dataset, src"),
    (sim_main, ["generate", "--frames", "x", "--out", "o"], "--frames was removed: use --set path.frames=N"),
    (sim_main, ["contact-sheet"], "the following arguments are required"),
    (models_main, ["fit", "--nope", "1"], "unrecognized arguments: --nope 1"),
    (models_main, ["bogus"], "invalid choice: 'bogus'"),
    (models_main, [], 'expected "subcommand" to be one of'),
]


@pytest.mark.parametrize("main,argv,expected", CASES, ids=[f"{m.__module__}:{' '.join(a)}" for m, a, _ in CASES])
def test_usage_error_is_one_line(main, argv, expected, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and expected in err[0], err
