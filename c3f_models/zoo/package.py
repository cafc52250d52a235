"""From a finished recipe run to a zoo entry: float16 weights, ONNX export, held-out
evaluation, model card; then the entry replaces ``ZOO/NAME`` in one move.

Everything is made in ``WORK/package/`` first. The weights are rounded to float16 once
(``weights.safetensors``) and the ONNX file is exported from those rounded weights, with the
recipe's storage (float16: the exporter's batch-norm folding rounds the folded weights once
more, which the parity check bounds); the card reports what the rounding costs on the held-out
numbers (the same evaluation of the float32 checkpoint).
"""

from __future__ import annotations

import json
import os
import shutil
import time
from pathlib import Path

import torch
import yaml

from c3f_core.errors import InputError
from c3f_models.checkpoints import read_checkpoint_weights
from c3f_models.zoo.card import training_record, write_card, write_index
from c3f_models.zoo.evaluate import depth_heldout, descriptor_heldout
from c3f_models.zoo.recipes import Recipe, SimSpec
from c3f_models.zoo.train import RecipeRun, newest_checkpoint, run_module, simulate
from c3f_slam.models.zoo import sha256_of

ONNX_FILE = {"depth": "depthnet.onnx", "pose": "posenet.onnx", "descriptors": "contrafeat.onnx"}
WEIGHTS = "weights.safetensors"


def half_state(state: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """The state dict with every floating tensor as float16 (others unchanged); InputError when
    a value does not fit float16 (non-finite after rounding)."""
    out = {}
    for k, v in state.items():
        if v.is_floating_point():
            h = v.detach().to(torch.float16)
            if not torch.isfinite(h).all():
                raise InputError(f"{k}: does not fit float16 (values up to {v.abs().max().item():.3g})")
            out[k] = h.contiguous()
        else:
            out[k] = v.detach().contiguous()
    return out


def write_weights(ckpt: Path, out: Path, recipe: Recipe) -> Path:
    from safetensors.torch import save_file

    state = half_state(read_checkpoint_weights(ckpt, "checkpoint"))
    save_file(state, str(out), metadata={"format": "pt", "recipe": recipe.name, "dtype": "float16",
                                         "keys": "LightningModule state_dict"})
    return out


def model_config(run: RecipeRun) -> dict:
    """The model part of the fit's resolved config (class path and init args), ``init_weights``
    cleared: what the weights fit (``--config zoo/NAME/config.yaml`` rebuilds the model)."""
    saved = yaml.safe_load(run.config.read_text())
    model = saved["model"]
    model.setdefault("init_args", {})["init_weights"] = None
    data = {k: saved["data"]["init_args"][k] for k in ("frames", "sampling") if k in saved["data"]["init_args"]}
    return {"model": model, "data": {"class_path": saved["data"]["class_path"], "init_args": data}}


def export(run: RecipeRun, weights: Path, out: Path, storage: str = "float16") -> dict:
    """``python -m c3f_models export`` of ``weights`` with the run's config; returns export.json."""
    graphs = "[" + ",".join(run.recipe.graphs) + "]"
    run_module(["-m", "c3f_models", "export", "--config", str(run.config), "--ckpt_path", str(weights),
                "--output_dir", str(out), "--graphs", graphs, "--storage", storage], f"export of {run.recipe.name}")
    return json.loads((out / "export.json").read_text())




def evaluate(run: RecipeRun, stage: Path, heldout: list[Path], ckpt: Path) -> dict:
    """The held-out numbers of the packaged model, and the same for the float32 checkpoint
    (``*_float32``: what the float16 rounding of the shipped files costs)."""
    if run.recipe.kind == "depth":
        export(run, ckpt, stage / "float32", storage="float32")
        return {"depth": depth_heldout(stage / ONNX_FILE["depth"], heldout),
                "depth_float32": depth_heldout(stage / "float32" / ONNX_FILE["depth"], heldout)}
    from c3f_models.contrafeat.module import ContraFeat

    cfg = model_config(run)["model"]["init_args"]
    out = {}
    for key, weights in (("descriptors", stage / WEIGHTS), ("descriptors_float32", ckpt)):
        model = ContraFeat(**{k: v for k, v in cfg.items() if k != "init_weights"})
        model.load_init_weights(weights)
        model.eval()
        out[key] = descriptor_heldout(model, heldout[0].parent, [p.name for p in heldout])
    return out


def package(run: RecipeRun, zoo_dir: Path, heldout: tuple[SimSpec, ...], heldout_root: Path) -> Path:
    """Make the entry of ``run`` (a finished recipe), evaluated on the ``heldout`` sequences
    (generated into ``heldout_root`` when missing), and move it to ``zoo_dir/NAME``."""
    r = run.recipe
    ckpt, step = newest_checkpoint(run)
    if ckpt is None or step < r.steps:
        raise InputError(f"{r.name}: the fit is not finished ({step} of {r.steps} steps); run zoo train again")
    stage = run.work / "package"
    shutil.rmtree(stage, ignore_errors=True)
    stage.mkdir(parents=True)
    write_weights(ckpt, stage / WEIGHTS, r)
    (stage / "config.yaml").write_text(yaml.safe_dump(model_config(run), sort_keys=False))
    export(run, stage / WEIGHTS, stage / "onnx", storage=r.storage)
    for kind in r.graphs:
        os.replace(stage / "onnx" / ONNX_FILE[kind], stage / ONNX_FILE[kind])
    t0 = time.time()
    results = evaluate(run, stage, simulate(heldout, 128, heldout_root), ckpt)
    results["evaluation_wall_s"] = round(time.time() - t0, 1)
    (stage / "evaluation.json").write_text(json.dumps(results, indent=2) + "\n")
    files = {name: {"role": role, "sha256": sha256_of(stage / name), "bytes": (stage / name).stat().st_size}
             for name, role in _entry_files(r).items()}
    write_card(stage / "README.md", r, training=training_record(r, run.read_state(), step), files=files,
               results=results, heldout=heldout)
    dest = install(stage, zoo_dir / r.name, [*files, "README.md", "config.yaml", "evaluation.json"])
    write_index(zoo_dir)
    return dest


def _entry_files(r: Recipe) -> dict[str, str]:
    """File name -> role of an entry of recipe ``r``."""
    return {**{ONNX_FILE[k]: k for k in r.graphs}, WEIGHTS: "weights"}


def install(stage: Path, dest: Path, names: list[str]) -> Path:
    """Copy ``names`` of ``stage`` into a hidden folder beside ``dest``, then swap it in (the old
    entry, if any, is removed only after the new one is complete)."""
    dest.parent.mkdir(parents=True, exist_ok=True)
    tmp = dest.parent / f".{dest.name}.new"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    for name in names:
        shutil.copy2(stage / name, tmp / name)
    old = dest.parent / f".{dest.name}.old"
    shutil.rmtree(old, ignore_errors=True)
    if dest.exists():
        os.replace(dest, old)
    os.replace(tmp, dest)
    shutil.rmtree(old, ignore_errors=True)
    return dest


__all__ = ["ONNX_FILE", "WEIGHTS", "half_state", "install", "package"]
