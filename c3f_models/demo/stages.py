"""The demo's stages before evaluation: simulate -> train_depth -> train_features -> export -> slam.

Each stage is a small class: ``settings`` (what its key hashes), ``outputs`` (what it writes,
removed before it reruns after an interruption), ``estimate_s`` (seconds on 2 CPU cores, for
the ETA), ``probe`` (fraction done, when known) and ``run`` (returns notes for the report).
Every step is the project's own command line (README), run by :meth:`DemoContext.run`.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import asdict
from pathlib import Path

import yaml

from c3f_models.demo.config import DemoConfig
from c3f_models.demo.context import CONFIGS, SLAM_RUNS, DemoContext, StageFailed
from c3f_models.demo.progress import read_step_fraction


class Stage:
    """Base: a named step with upstream stages (their keys enter this stage's key)."""

    name = ""
    upstream: tuple[str, ...] = ()

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
        return [ctx.root / "data", ctx.log(self.name)]

    def estimate_s(self, cfg):
        s = cfg.simulate
        return 6.0 * (len(s.train) + 1) + 0.04 * (s.train_frames * len(s.train) + s.test_frames) * (s.size / 128) ** 2

    def probe(self, ctx):
        s = ctx.cfg.simulate
        total = s.train_frames * len(s.train) + s.test_frames

        def done() -> float:
            n = sum(len(list(p.glob("*.png"))) for p in ctx.root.glob("data/*/*/rgb"))
            return n / total
        return done

    def _generate(self, ctx: DemoContext, preset: str, seed: int, frames: int, coverage: float, out: Path) -> None:
        s = ctx.cfg.simulate
        ctx.run(self.name, ["-m", "datamodules.synthetic", "generate", "--preset", preset, "--seed", str(seed),
                            "--frames", str(frames), "--size", str(s.size), "--set", f"path.coverage={coverage}",
                            "--out", str(out), "--no-progress"])

    def run(self, ctx, done=None):
        s = ctx.cfg.simulate
        for k, (preset, seed) in enumerate(s.train):
            self._generate(ctx, preset, seed, s.train_frames, s.train_coverage, ctx.train_data / f"train{k}")
        self._generate(ctx, *s.test, s.test_frames, s.test_coverage, ctx.test_seq)
        return {"train": [f"train{k}" for k in range(len(s.train))], "test": "heldout"}


def _fit_yaml(ctx: DemoContext, model: str, steps: int, seed: int, model_args: dict, data_args: dict) -> Path:
    """The demo's last config file of a ``fit``: trainer length, logging into DIR/runs/MODEL, data."""
    run = ctx.run_dir(model)
    cfg = {
        "seed_everything": seed,
        "trainer": {
            "max_steps": steps, "max_epochs": -1, "limit_train_batches": 1.0, "limit_val_batches": 0,
            "log_every_n_steps": 5, "enable_progress_bar": False, "default_root_dir": str(run),
            "logger": {"class_path": "lightning.pytorch.loggers.TensorBoardLogger",
                       "init_args": {"save_dir": str(run), "name": "tb"}},
            "callbacks": [
                {"class_path": "lightning.pytorch.callbacks.ModelCheckpoint", "init_args": {"save_last": True}},
                {"class_path": "c3f_models.demo.progress.ProgressFile",
                 "init_args": {"path": str(run / "progress.txt")}},
            ],
        },
        "model": {"init_args": model_args},
        "data": {"init_args": {"data_dir": str(ctx.train_data), **data_args}},
    }
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


class TrainDepth(_Training):
    """DepthNet (``configs/depthnet/small.yaml``) on the training sequences."""

    name, model, group = "train_depth", "depthnet", "depth"

    def estimate_s(self, cfg):
        return 15.0 + cfg.depth.steps * 0.5 * (cfg.depth.size / 64) ** 2 * (3 if cfg.depth.paper_extras else 1)

    def run(self, ctx, done=None):
        d = ctx.cfg.depth
        model_args = {"loss": {"lambda_gt_depth": d.lambda_gt_depth}}
        if d.lr is not None:
            model_args["optim"] = {"lr": d.lr}
        data_args = {"split": _train_split(ctx), "frames": {"size": [d.size, d.size]},
                     "loader": {"batch_size": d.batch_size, "num_workers": 0}}
        mine = _fit_yaml(ctx, "depthnet", d.steps, d.seed, model_args, data_args)
        configs = [CONFIGS / "trainer" / "cpu_smoke.yaml", CONFIGS / "depthnet" / "small.yaml"]
        if not d.paper_extras:
            configs.append(CONFIGS / "depthnet" / "monodepth2.yaml")
        ctx.run(self.name, ["-m", "c3f_models", "fit", *_config_args(configs + [mine])])
        return {"configs": [str(c) for c in configs + [mine]], "checkpoint": str(_last_ckpt(ctx, "depthnet"))}


class TrainFeatures(_Training):
    """ContraFeat (``configs/contrafeat/small.yaml``) on the training sequences."""

    name, model, group = "train_features", "contrafeat", "features"

    def estimate_s(self, cfg):
        return 15.0 + cfg.features.steps * 1.5 * (cfg.features.size / 128) ** 2

    def run(self, ctx, done=None):
        f = ctx.cfg.features
        data_args = {"split": _train_split(ctx), "frames": {"crop": None, "size": [f.size, f.size], "specular": True},
                     "loader": {"batch_size": f.batch_size, "num_workers": 0}}
        mine = _fit_yaml(ctx, "contrafeat", f.steps, f.seed, {}, data_args)
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
    """Both trained networks to ONNX (``python -m c3f_models export``, with its parity check)."""

    name = "export"
    upstream = ("train_depth", "train_features")

    def outputs(self, ctx):
        return [ctx.models, ctx.log(self.name)]

    def estimate_s(self, cfg):
        return 60.0

    def run(self, ctx, done=None):
        for model in ("depthnet", "contrafeat"):
            v = ctx.version_dir(model)
            ctx.run(self.name, ["-m", "c3f_models", "export", "--config", str(v / "config.yaml"),
                                "--ckpt_path", str(v / "checkpoints" / "last.ckpt"),
                                "--output_dir", str(ctx.models / model)])
        meta = json.loads((ctx.models / "depthnet" / "export.json").read_text())
        return {"depthnet_export": meta.get("files", meta)}


class Slam(Stage):
    """``c3f_slam run`` on the held-out sequence in every configuration of :data:`SLAM_RUNS`.

    A configuration that fails (e.g. no frame registered) is recorded as failed with its error
    line; the stage goes on with the others."""

    name = "slam"
    upstream = ("simulate", "export")

    def settings(self, cfg):
        return {name: opts for name, (_, opts) in SLAM_RUNS.items()}

    def outputs(self, ctx):
        return [ctx.root / "slam", ctx.log(self.name)]

    def estimate_s(self, cfg):
        return 3 * 8.0 + cfg.simulate.test_frames * (0.05 + 2 * 0.25)

    def probe(self, ctx):
        return lambda: sum(ctx.slam_dir(n).is_dir() for n in SLAM_RUNS) / (len(SLAM_RUNS) + 1)

    def run(self, ctx, done=None):
        results = {}
        for name, (title, opts) in SLAM_RUNS.items():
            args = [o.format(models=ctx.models) for o in opts]
            try:
                ctx.run(self.name, ["-m", "c3f_slam", "run", str(ctx.test_seq), *args,
                                    "--out", str(ctx.slam_dir(name)), "--quiet"])
                results[name] = {"title": title, "status": "ok"}
            except StageFailed as exc:
                results[name] = {"title": title, "status": "failed", "error": str(exc)}
        return {"runs": results}
