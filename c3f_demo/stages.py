"""The demo's stages before evaluation: simulate -> train_depth -> ttt_depth -> train_features ->
export -> slam.

Each stage is a small class: ``settings`` (what its key hashes), ``outputs`` (what it writes,
removed before it reruns after an interruption), ``estimate_s`` (seconds on 2 CPU cores, for
the ETA), ``probe`` (fraction done, when known) and ``run`` (returns notes for the report).
Every step is the project's own command line (docs/demo.md), run by :meth:`DemoContext.run`.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import asdict
from pathlib import Path
from typing import Any

import yaml

from c3f_core.settings_cli import merge
from c3f_demo.config import DemoConfig
from c3f_demo.context import CONFIGS, DemoContext, StageFailed, slam_runs
from c3f_demo.progress import read_step_fraction


class Stage:
    """Base: a named step with upstream stages (their keys enter this stage's key)."""

    name = ""
    upstream: tuple[str, ...] = ()

    def inputs(self, cfg: DemoConfig) -> tuple[str, ...]:
        """The stages this one reads from for ``cfg``: ``upstream``, where the sequence stage
        ``simulate`` is ``ingest`` on a user's video."""
        return tuple("ingest" if u == "simulate" and cfg.video else u for u in self.upstream)

    def settings(self, cfg: DemoConfig) -> dict:
        return {}

    def outputs(self, ctx: DemoContext) -> list[Path]:
        return []

    def estimate_s(self, cfg: DemoConfig) -> float:
        return 10.0

    def probe(self, ctx: DemoContext):
        return None

    def run(self, ctx: DemoContext, done: dict | None = None) -> dict:
        """Do the work; ``done``: ``notes`` of the finished stages (name -> dict) and ``timings`` so far."""
        raise NotImplementedError

    def clean(self, ctx: DemoContext) -> None:
        """Remove what an unfinished earlier attempt of this stage left (never another stage's files)."""
        for p in self.outputs(ctx):
            if p.is_dir():
                shutil.rmtree(p)
            elif p.exists():
                p.unlink()


class Simulate(Stage):
    """Training sequences and the held-out one, with exact depth, poses and mesh."""

    name = "simulate"

    def settings(self, cfg):
        return asdict(cfg.simulate)

    def outputs(self, ctx):
        return [ctx.root / "data", *(ctx.log(f"{self.name}_{k}") for k in self._commands(ctx))]

    def estimate_s(self, cfg):
        s = cfg.simulate
        one = 6.0 * (len(s.train) + 1) + 0.04 * (s.train_frames * len(s.train) + s.test_frames) * (s.size / 128) ** 2
        return one / 2  # 2 at a time

    def probe(self, ctx):
        s = ctx.cfg.simulate
        total = s.train_frames * len(s.train) + s.test_frames

        def done() -> float:
            n = sum(len(list(p.glob("*.png"))) for p in ctx.root.glob("data/*/*/rgb"))
            return n / total
        return done

    def _commands(self, ctx: DemoContext) -> dict[str, list[str]]:
        """Sequence name -> its ``generate`` command."""
        s = ctx.cfg.simulate
        seqs = {f"train{k}": (preset, seed, s.train_frames, s.train_coverage, ctx.train_data / f"train{k}")
                for k, (preset, seed) in enumerate(s.train)}
        seqs["heldout"] = (*s.test, s.test_frames, s.test_coverage, ctx.test_seq)
        return {name: ["-m", "datamodules.synthetic", "generate", "--preset", preset, "--set", f"seed={seed}",
                       "--set", f"path.frames={frames}", "--set", f"camera.width={s.size}",
                       "--set", f"camera.height={s.size}", "--set", f"path.coverage={coverage}",
                       "--out", str(out), "--no-progress"]
                for name, (preset, seed, frames, coverage, out) in seqs.items()}

    def run(self, ctx, done=None):
        for exc in ctx.run_many(self.name, self._commands(ctx)).values():
            if exc is not None:
                raise exc
        return {"train": [f"train{k}" for k in range(len(ctx.cfg.simulate.train))], "test": "heldout"}


#: where the fields of a training group (``depth``, ``ttt``, ``features``) go in a ``fit`` config
#: (dotted paths; a ``size`` is square: ``[size, size]``)
FIT_KEYS = {"steps": "trainer.max_steps", "seed": "seed_everything", "lr": "model.init_args.optim.lr",
            "lambda_gt_depth": "model.init_args.loss.lambda_gt_depth",
            "pose_warmup_steps": "model.init_args.pose_warmup_steps",
            "batch_size": "data.init_args.loader.batch_size", "size": "data.init_args.frames.size"}


def fit_keys(group: Any, skip: tuple[str, ...] = ()) -> dict[str, Any]:
    """The fields of settings ``group`` as dotted ``fit`` config keys (:data:`FIT_KEYS`); a None
    field is left to the model config, ``skip``: fields that pick config files instead. KeyError
    for a field with no place (a new setting must be given one)."""
    return {FIT_KEYS[k]: [v, v] if k == "size" else v for k, v in asdict(group).items()
            if k not in skip and v is not None}


def _nested(flat: dict[str, Any]) -> dict[str, Any]:
    """``{"a.b": 1}`` -> ``{"a": {"b": 1}}``."""
    out: dict[str, Any] = {}
    for path, value in flat.items():
        head, _, rest = path.partition(".")
        out = merge(out, {head: _nested({rest: value}) if rest else value})
    return out


def _fit_yaml(ctx: DemoContext, model: str, settings: dict[str, Any], data_dir: Path | None = None,
              callbacks_of: Path | None = None) -> Path:
    """The demo's last config file of a ``fit``: ``settings`` (dotted keys, e.g. :func:`fit_keys`),
    logging into DIR/runs/MODEL, data (``data_dir``: default the training sequences). Its callbacks
    replace the earlier configs' (a list is not merged): a last checkpoint and the demo's progress
    file, after the callbacks of the config ``callbacks_of`` (e.g. ``ttt.yaml``'s test-time
    training guard) when given."""
    run = ctx.run_dir(model)
    kept = yaml.safe_load(callbacks_of.read_text())["trainer"]["callbacks"] if callbacks_of else [
        {"class_path": "lightning.pytorch.callbacks.ModelCheckpoint", "init_args": {"save_last": True}}]
    cfg = {
        "trainer": {
            "max_epochs": -1, "limit_train_batches": 1.0, "limit_val_batches": 0,
            "log_every_n_steps": 5, "enable_progress_bar": False, "default_root_dir": str(run),
            "logger": {"class_path": "lightning.pytorch.loggers.TensorBoardLogger",
                       "init_args": {"save_dir": str(run), "name": "tb"}},
            "callbacks": [
                *kept,
                {"class_path": "c3f_demo.progress_callback.ProgressFile",
                 "init_args": {"path": str(run / "progress.txt")}},
            ],
        },
        "data": {"init_args": {"data_dir": str(data_dir or ctx.train_data), "loader": {"num_workers": 0}}},
    }
    cfg = merge(cfg, _nested(settings))
    path = ctx.root / "configs" / f"{model}_demo.yaml"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(cfg, sort_keys=False))
    return path


def _train_split(ctx: DemoContext) -> dict:
    names = [f"train{k}" for k in range(len(ctx.cfg.simulate.train))]
    return {"train": names, "val": [], "test": [], "val_fraction": 0.0, "test_fraction": 0.0}


class _Training(Stage):
    """A ``fit`` of ``model`` on the training sequences, settings from ``cfg.<group>``."""

    model = group = ""
    upstream = ("simulate",)

    def settings(self, cfg):
        """The group's fields; those left unset (None) do not enter the key."""
        return {k: v for k, v in asdict(getattr(cfg, self.group)).items() if v is not None}

    def outputs(self, ctx):
        return [ctx.run_dir(self.model), ctx.log(self.name), ctx.root / "configs" / f"{self.model}_demo.yaml"]

    def probe(self, ctx):
        return lambda: read_step_fraction(ctx.run_dir(self.model) / "progress.txt")


def _depth_model_configs(cfg: DemoConfig) -> list[Path]:
    """The trainer preset and DepthNet model configs of both depth fits (same architecture)."""
    configs = [CONFIGS / "trainer" / "cpu_smoke.yaml", CONFIGS / "depthnet" / "small.yaml"]
    if not cfg.depth.paper_extras:
        configs.append(CONFIGS / "depthnet" / "monodepth2.yaml")
    return configs


def _zoo_note(kind: str, name: str) -> dict:
    """What the report says of a zoo model: its name, card summary, held-out numbers, training."""
    from c3f_slam.models import zoo
    e = zoo.entry(name, "demo")
    card = e.own
    return {"zoo": name, "kind": kind, "summary": e.summary, "metrics": e.metrics,
            "training": card.get("training", {}), "card": str(e.folder / zoo.CARD)}


class _ZooOrTrain(_Training):
    """A training stage that, when the demo starts from the zoo, trains nothing: the zoo entry
    (checked: name, kind, files' SHA-256) stands in for the run."""

    zoo_field = ""

    def settings(self, cfg):
        if cfg.from_zoo:
            return {"zoo": getattr(cfg.zoo, self.zoo_field)}
        return super().settings(cfg)

    def outputs(self, ctx):
        return [] if ctx.cfg.from_zoo else super().outputs(ctx)

    def probe(self, ctx):
        return None if ctx.cfg.from_zoo else super().probe(ctx)


class TrainDepth(_ZooOrTrain):
    """DepthNet (``configs/depthnet/small.yaml``) on the training sequences (the pre-training), or
    the zoo's DepthNet."""

    name, model, group, zoo_field = "train_depth", "depthnet", "depth", "depth"

    def estimate_s(self, cfg):
        if cfg.from_zoo:
            return 2.0
        return 15.0 + cfg.depth.steps * 0.5 * (cfg.depth.size / 64) ** 2 * (3 if cfg.depth.paper_extras else 1)

    def run(self, ctx, done=None):
        if ctx.cfg.from_zoo:
            from c3f_slam.models import zoo
            zoo.entry(ctx.cfg.zoo.depth, "demo").file_for("weights", "demo", kind="depth")  # checked now
            return _zoo_note("depth", ctx.cfg.zoo.depth)
        mine = _fit_yaml(ctx, "depthnet", {**fit_keys(ctx.cfg.depth, skip=("paper_extras",)),
                                           "data.init_args.split": _train_split(ctx)})
        configs = [*_depth_model_configs(ctx.cfg), mine]
        ctx.run(self.name, ["-m", "c3f_models", "fit", *_config_args(configs)])
        return {"configs": [str(c) for c in configs], "checkpoint": str(_last_ckpt(ctx, "depthnet"))}


class TestTimeTrain(_Training):
    """Self-supervised test-time training of the pre-trained DepthNet on the held-out sequence
    (``configs/depthnet/ttt.yaml``: from ``--model.init_weights``, every frame, no ground truth:
    ``lambda_gt_depth`` 0). ``ttt.steps`` 0: nothing runs, the pre-trained network is used."""

    name, model, group = "ttt_depth", "depthnet_ttt", "ttt"
    upstream = ("simulate", "train_depth")
    __test__ = False  # not a pytest class

    def settings(self, cfg):
        if cfg.from_zoo:
            return {**super().settings(cfg), "zoo": cfg.zoo.depth, "objective": "paper"}
        return {**super().settings(cfg), "size": cfg.depth.size, "paper_extras": cfg.depth.paper_extras}

    def estimate_s(self, cfg):
        if cfg.ttt.steps == 0:
            return 1.0
        if cfg.from_zoo:  # the paper's objective at 128 px, half-width encoders
            return 15.0 + cfg.ttt.steps * 1.0 * cfg.ttt.batch_size / 4
        per_step = 0.5 * (cfg.depth.size / 64) ** 2 * (3 if cfg.depth.paper_extras else 1) * cfg.ttt.batch_size / 4
        return 15.0 + cfg.ttt.steps * per_step

    def run(self, ctx, done=None):
        t, d = ctx.cfg.ttt, ctx.cfg.depth
        if t.steps == 0:
            return {"off": True}
        if ctx.cfg.from_zoo:
            return self._from_zoo(ctx)
        ttt = CONFIGS / "depthnet" / "ttt.yaml"
        mine = _fit_yaml(ctx, self.model, {**fit_keys(t), FIT_KEYS["size"]: [d.size, d.size],  # the pre-training's
                                           "model.init_args.init_weights": str(_last_ckpt(ctx, "depthnet")),
                                           "model.init_args.loss.lambda_gt_depth": 0.0},
                         data_dir=ctx.test_seq, callbacks_of=ttt)
        configs = [*_depth_model_configs(ctx.cfg), ttt, mine]
        ctx.run(self.name, ["-m", "c3f_models", "fit", *_config_args(configs)])
        return {"configs": [str(c) for c in configs], "checkpoint": str(_last_ckpt(ctx, self.model))}


    def _from_zoo(self, ctx: DemoContext) -> dict:
        """From the zoo weights with the paper's objective (``configs/depthnet/paper_objective.yaml``)
        and the zoo entry's model and frame settings."""
        from c3f_slam.models import zoo
        t, name = ctx.cfg.ttt, ctx.cfg.zoo.depth
        ttt = CONFIGS / "depthnet" / "ttt.yaml"
        mine = _fit_yaml(ctx, self.model, {**fit_keys(t), "model.init_args.init_weights": f"zoo:{name}"},
                         data_dir=ctx.test_seq, callbacks_of=ttt)
        configs = [zoo.entry(name, "demo").folder / "config.yaml", ttt, CONFIGS / "depthnet" / "paper_objective.yaml",
                   mine]
        ctx.run(self.name, ["-m", "c3f_models", "fit", *_config_args(configs)])
        guard = ctx.version_dir(self.model) / "checkpoints" / "guard.json"
        return {"configs": [str(c) for c in configs], "checkpoint": str(_last_ckpt(ctx, self.model)),
                "guard": json.loads(guard.read_text()) if guard.is_file() else None}


class TrainFeatures(_ZooOrTrain):
    """ContraFeat (``configs/contrafeat/small.yaml``) on the training sequences, or the zoo's."""

    name, model, group, zoo_field = "train_features", "contrafeat", "features", "features"

    def estimate_s(self, cfg):
        if cfg.from_zoo:
            return 2.0
        return 15.0 + cfg.features.steps * 0.8 * (cfg.features.size / 128) ** 2

    def run(self, ctx, done=None):
        if ctx.cfg.from_zoo:
            from c3f_slam.models import zoo
            zoo.entry(ctx.cfg.zoo.features, "demo").file_for("descriptors", "demo")  # checked now
            return _zoo_note("descriptors", ctx.cfg.zoo.features)
        mine = _fit_yaml(ctx, "contrafeat", {**fit_keys(ctx.cfg.features), "data.init_args.split": _train_split(ctx),
                                             "data.init_args.frames.crop": None,
                                             "data.init_args.frames.specular": True})
        configs = [CONFIGS / "trainer" / "cpu_smoke.yaml", CONFIGS / "contrafeat" / "small.yaml", mine]
        ctx.run(self.name, ["-m", "c3f_models", "fit", *_config_args(configs)])
        return {"configs": [str(c) for c in configs], "checkpoint": str(_last_ckpt(ctx, "contrafeat"))}


def _config_args(paths: list[Path]) -> list[str]:
    return [a for p in paths for a in ("--config", str(p))]


def _last_ckpt(ctx: DemoContext, model: str) -> Path:
    ckpt = ctx.version_dir(model) / "checkpoints" / "last.ckpt"
    if not ckpt.is_file():
        raise StageFailed(f"{ckpt}: the training run wrote no checkpoint")
    return ckpt


class Export(Stage):
    """The trained networks to ONNX (``python -m c3f_models export``, with its parity check):
    ``models/depthnet`` (the test-time trained DepthNet, which SLAM uses; the pre-trained one when
    test-time training is off), ``models/depthnet_pretrained`` (before test-time training, for the
    depth metrics before/after) and ``models/contrafeat``. Every export uses its training run's
    config, so the metric depth scale is measured on the training sequences, never the held-out one."""

    name = "export"
    upstream = ("train_depth", "ttt_depth", "train_features")

    def outputs(self, ctx):
        return [ctx.models, *(ctx.log(f"{self.name}_{k}") for k in self._jobs(ctx))]

    def estimate_s(self, cfg):
        return 50.0 if cfg.ttt.steps else 35.0  # 2 at a time; a pose graph doubles a DepthNet export

    def _jobs(self, ctx: DemoContext) -> dict[str, tuple[str, str, list[str]]]:
        """Output folder -> (training run whose config is used, run whose checkpoint, extra options)."""
        tuned = ctx.cfg.ttt.steps > 0
        jobs = {"depthnet": ("depthnet", "depthnet_ttt" if tuned else "depthnet", [])}
        if tuned:  # for the metrics before/after and SLAM without TTT; c3f_slam needs no PoseNet
            jobs["depthnet_pretrained"] = ("depthnet", "depthnet", ["--graphs", "[depth]"])
        jobs["contrafeat"] = ("contrafeat", "contrafeat", [])
        return jobs

    def run(self, ctx, done=None):
        if ctx.cfg.from_zoo:
            return self._from_zoo(ctx)
        jobs = {folder: (ctx.version_dir(run) / "config.yaml", _last_ckpt(ctx, weights), extra)
                for folder, (run, weights, extra) in self._jobs(ctx).items()}
        failed = ctx.run_many(self.name, {
            folder: ["-m", "c3f_models", "export", "--config", str(config), "--ckpt_path", str(ckpt),
                     "--output_dir", str(ctx.models / folder), *extra]
            for folder, (config, ckpt, extra) in jobs.items()})
        for exc in failed.values():
            if exc is not None:
                raise exc
        meta = json.loads((ctx.models / "depthnet" / "export.json").read_text())
        return {"depthnet_export": meta.get("files", meta), "depthnet_checkpoint": str(jobs["depthnet"][1])}


    def _from_zoo(self, ctx: DemoContext) -> dict:
        """The zoo's ONNX files as they are (``depthnet_pretrained``, ``contrafeat``) and, after
        test-time training, the tuned DepthNet exported with the zoo model's recorded metric scale
        (nothing is measured on the held-out sequence's true depth)."""
        from c3f_slam.models import zoo
        from c3f_slam.models.nets import DepthModel

        depth = zoo.entry(ctx.cfg.zoo.depth, "demo")
        pretrained = _copy_zoo_file(depth, "depth", ctx.models / "depthnet_pretrained")
        _copy_zoo_file(zoo.entry(ctx.cfg.zoo.features, "demo"), "descriptors", ctx.models / "contrafeat")
        if ctx.cfg.ttt.steps == 0:
            _copy_zoo_file(depth, "depth", ctx.models / "depthnet")
            return {"depthnet_export": {"source": f"zoo:{depth.name}"}}
        scale = DepthModel(pretrained).metric_scale
        config = ctx.version_dir("depthnet_ttt") / "config.yaml"
        ctx.run(f"{self.name}_depthnet", [
            "-m", "c3f_models", "export", "--config", str(config), "--ckpt_path", str(_last_ckpt(ctx, "depthnet_ttt")),
            "--output_dir", str(ctx.models / "depthnet"), "--graphs", "[depth]", "--frames", str(ctx.test_seq),
            *(["--metric_scale", repr(scale)] if scale is not None else [])])
        meta = json.loads((ctx.models / "depthnet" / "export.json").read_text())
        return {"depthnet_export": meta.get("files", meta), "metric_scale_from": f"zoo:{depth.name}"}


def _copy_zoo_file(entry, role: str, folder: Path) -> Path:
    """The zoo entry's verified file of ``role`` copied into ``folder`` (for the report and the
    SLAM runs' commands); returns the copy."""
    src = entry.file_for(role, "demo")
    folder.mkdir(parents=True, exist_ok=True)
    shutil.copy2(src, folder / src.name)
    return folder / src.name


class Slam(Stage):
    """``c3f_slam run`` on the held-out sequence in every configuration of :func:`slam_runs`.

    A configuration that fails (e.g. no frame registered) is recorded as failed with its error
    line; the stage goes on with the others."""

    name = "slam"
    upstream = ("simulate", "export")

    def settings(self, cfg):
        return {name: opts for name, (_, opts) in slam_runs(cfg).items()}

    def outputs(self, ctx):
        return [ctx.root / "slam", *(ctx.log(f"{self.name}_{n}") for n in ctx.slam_runs)]

    def estimate_s(self, cfg):
        n = len(slam_runs(cfg))  # 2 at a time
        return (n * 8.0 + cfg.sequence_frames * (0.05 + (n - 1) * 0.25)) / 2

    def probe(self, ctx):
        return lambda: sum(ctx.slam_dir(n).is_dir() for n in ctx.slam_runs) / (len(ctx.slam_runs) + 1)

    def run(self, ctx, done=None):
        runs = ctx.slam_runs
        failed = ctx.run_many(self.name, {
            name: ["-m", "c3f_slam", "run", str(ctx.test_seq), *[o.format(models=ctx.models) for o in opts],
                   "--out", str(ctx.slam_dir(name)), "--quiet"]
            for name, (_, opts) in runs.items()})
        return {"runs": {name: {"title": runs[name][0], "status": "ok"} if exc is None else
                         {"title": runs[name][0], "status": "failed", "error": str(exc)}
                         for name, exc in failed.items()}}
