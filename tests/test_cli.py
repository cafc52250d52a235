"""The `python -m c3f_models` CLI: help without data, clear one-line errors."""

import subprocess
import sys
from pathlib import Path

import pytest

from c3f_models.cli import main
from tests.startup import packages_loaded_by

ROOT = Path(__file__).resolve().parents[1]
BORING = "lightning.pytorch.demos.boring_classes.BoringModel"
DATA = "datamodules.sequence.C3FSequenceDataModule"


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "c3f_models", *args], cwd=ROOT, capture_output=True, text=True, timeout=300
    )


@pytest.mark.e2e
def test_help_without_data():
    out = _cli("--help")
    assert out.returncode == 0
    for sub in ("fit", "validate", "test", "predict"):
        assert sub in out.stdout
    out = _cli("fit", "--help")
    assert out.returncode == 0 and "--ckpt_path" in out.stdout and "--seed_everything" in out.stdout


def test_missing_data_dir_one_line_error(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["fit", "--model", BORING, "--data", DATA, "--data.data_dir", str(tmp_path / "nowhere"),
              "--trainer.default_root_dir", str(tmp_path), "--trainer.logger", "false"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"error: data.data_dir: folder not found: {tmp_path / 'nowhere'}"]


def test_unknown_config_key(tmp_path, capsys):
    cfg = tmp_path / "bad.yaml"
    cfg.write_text(f"model:\n  class_path: {BORING}\ndata:\n  class_path: {DATA}\n"
                   "  init_args:\n    data_dir: x\n    no_such_option: 3\n")
    with pytest.raises(SystemExit) as exc:
        main(["fit", "--config", str(cfg)])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and "'no_such_option' is not accepted" in err[0]


def test_missing_config_file(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["fit", "--config", str(tmp_path / "nope.yaml")])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nope.yaml" in err[0]


def test_condense_keeps_innermost_reason():
    from c3f_models.cli import condense_parser_error

    msg = (
        'Parser key "data":\n  Does not validate against any of the Union subtypes\n  Subtypes: [...]\n'
        "  Errors:\n    - Problem with given class_path 'a.B':\n        Option 'x' is not accepted\n"
        "    - Expected a <class 'NoneType'>\n  Given value type: <class 'dict'>\n"
    )
    assert condense_parser_error(msg) == 'Parser key "data": Option \'x\' is not accepted (in a.B)'


@pytest.mark.e2e
def test_models_are_exported_lazily():
    """``from c3f_models import DepthNet, ContraFeat`` works, but importing the package (and the
    CLI's --help) loads neither module, nor torch for the bare package."""
    code = (
        "import sys\n"
        "import c3f_models\n"
        "assert 'torch' not in sys.modules and 'c3f_models.depth.module' not in sys.modules\n"
        "from c3f_models.cli import main\n"
        "try:\n"
        "    main(['fit', '--help'])\n"
        "except SystemExit:\n"
        "    pass\n"
        "loaded = [m for m in ('c3f_models.depth.module', 'c3f_models.contrafeat.module') if m in sys.modules]\n"
        "assert not loaded, loaded\n"
        "from c3f_models import ContraFeat, DepthNet\n"
        "from c3f_models.contrafeat.module import ContraFeat as C\n"
        "from c3f_models.depth.module import DepthNet as D\n"
        "assert DepthNet is D and ContraFeat is C and 'DepthNet' in dir(c3f_models)\n"
        "try:\n"
        "    c3f_models.NoSuchModel\n"
        "except AttributeError:\n"
        "    print('lazy ok')\n"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=300,
                         check=False)
    assert out.returncode == 0 and out.stdout.strip().endswith("lazy ok"), out.stderr[-2000:]


def test_model_option_error_is_one_line(tmp_path, capsys):
    """A group's validation error, raised while the parser builds the model, ends in one line."""
    with pytest.raises(SystemExit) as exc:
        main(["fit", "--config", str(ROOT / "configs/depthnet/small.yaml"), "--model.network.min_depth", "0.5",
              "--data.data_dir", str(tmp_path), "--trainer.logger", "false"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["error: model.network.min_depth/max_depth: need 0 < min_depth < max_depth, got 0.5, 0.3"]


@pytest.mark.parametrize("argv", [["zoo", "list"], ["zoo", "show", "c3f-depth-r18w32", "--json"], ["zoo", "--help"],
                                  ["zoo", "recipes"]], ids=" ".join)
def test_zoo_commands_start_without_torch(argv):
    """Reading the zoo needs neither torch nor Lightning: ``python -m c3f_models zoo ...`` imports
    them not at all (LightningCLI's subcommands do, :mod:`c3f_models.lightning_cli`)."""
    loaded = packages_loaded_by("c3f_models", *argv)
    assert "c3f_models" in loaded and "c3f_slam" in loaded  # the command ran, and the check sees its imports
    assert not loaded & {"torch", "lightning", "jsonargparse", "torchvision"}, sorted(loaded)


def test_lightning_names_stay_importable_from_cli():
    """``c3f_models.cli`` still gives the LightningCLI's names (imported on first access)."""
    from c3f_models import cli, lightning_cli

    assert cli.C3FCLI is lightning_cli.C3FCLI and cli.EXTRA_SUBCOMMANDS == {"export": {"model", "datamodule"}}
    with pytest.raises(AttributeError):
        cli.NoSuchName  # noqa: B018
