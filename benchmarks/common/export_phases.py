"""Where the time of ``python -m c3f_models export`` goes, measured inside one such process.

    python -m benchmarks.common.export_phases --json OUT.json -- export --config ... --ckpt_path ...
    python -m benchmarks.common.export_phases --json OUT.json --variants 3 -- export --config ...

Without ``--variants``: the export runs as the command runs it, with timers around its steps
(:func:`install_timers`): importing torch and Lightning, importing the ONNX exporter, per graph
``torch.onnx.export`` split into its own steps (op registry, capture by ``torch.export``,
decomposition, translation to ONNX, the onnxscript optimiser; private functions of torch 2.14's
exporter, timed only where they exist), the parity check, the metric-scale calibration, and writing
the files; JSON ``{"steps": {name: seconds}}``. With ``--variants N``: nothing is written; per graph
the exporter variants of :data:`VARIANTS`, alternating, ``N`` times each; JSON ``{"variants": [...]}``.
Used by :mod:`benchmarks.studies.startup_export`.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import statistics
import time
import warnings
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path

STEPS: dict[str, float] = defaultdict(float)
#: the graph being exported (the label of the timers inside torch.onnx.export)
CURRENT = {"graph": ""}


def _timed(fn: Callable, name: Callable[[], str] | str) -> Callable:
    def wrapper(*args, **kwargs):
        t = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            STEPS[name() if callable(name) else name] += time.perf_counter() - t
    return wrapper


def _inside(step: str) -> Callable[[], str]:
    return lambda: f"{CURRENT['graph']}: torch.onnx.export: {step}"


def _timer_of_exporter() -> None:
    """Timers around torch.onnx.export's own steps (where this torch has them)."""
    from torch.onnx._internal.exporter import _capture_strategies, _core, _onnx_program, _registration

    for cls in _capture_strategies.CAPTURE_STRATEGIES:
        cls.__call__ = _timed(cls.__call__, _inside("capture (torch.export)"))
    _core._prepare_exported_program_for_export = _timed(_core._prepare_exported_program_for_export,
                                                        _inside("decompose"))
    _core._exported_program_to_onnx_program = _timed(_core._exported_program_to_onnx_program, _inside("translate"))
    _onnx_program.ONNXProgram.optimize = _timed(_onnx_program.ONNXProgram.optimize, _inside("optimize"))
    registry = _registration.ONNXRegistry.from_torchlib.__func__
    _registration.ONNXRegistry.from_torchlib = classmethod(_timed(registry, _inside("op registry")))


def install_timers() -> None:
    """Timers around the export's steps (:mod:`export.exporter`'s functions, looked up when it runs)."""
    import export
    import export.exporter as ex

    def to_onnx(module, *args, **kwargs):
        CURRENT["graph"] = type(module).__name__
        return _timed(original_to_onnx, _inside("total"))(module, *args, **kwargs)

    original_to_onnx = ex.to_onnx
    ex.to_onnx = to_onnx
    ex.check_parity = _timed(ex.check_parity, lambda: f"{CURRENT['graph']}: parity check")
    ex._metric_scale = _timed(ex._metric_scale, "metric-scale calibration")
    ex._write_export = _timed(ex._write_export, "write the files and export.json")
    ex.export_model = export.export_model = _timed(ex.export_model, "export_model (all of the above)")
    _timer_of_exporter()


def run_phases(export_args: list[str]) -> dict[str, float]:
    """Run the export with the timers; the seconds of each step (insertion order)."""
    t = time.perf_counter()
    import c3f_models.lightning_cli  # noqa: F401  (torch and Lightning)

    STEPS["import torch and Lightning"] = time.perf_counter() - t
    t = time.perf_counter()
    import onnxscript  # noqa: F401
    import torch.onnx._internal.exporter._core  # noqa: F401

    STEPS["import the ONNX exporter (torch.onnx, onnxscript)"] = time.perf_counter() - t
    install_timers()
    from c3f_models.cli import main

    t = time.perf_counter()
    main(export_args)
    STEPS["the export command after the imports"] = time.perf_counter() - t
    return dict(STEPS)


def _export_variant(variant: str, module, example: tuple, names: tuple[str, ...], output: str, opset: int):
    """The ONNX model proto of ``module`` exported as ``variant`` (:data:`VARIANTS`)."""
    import onnx
    import torch

    from export.onnx_io import MAX_SIZE, MIN_SIZE, to_onnx

    if variant in ("as used (dynamo, optimised, dynamic size)", "fixed frame size"):
        return to_onnx(module, example, names, output, opset, dynamic_size=variant != "fixed frame size")
    quiet = contextlib.redirect_stdout(io.StringIO())
    with warnings.catch_warnings(), quiet, torch.no_grad():
        warnings.simplefilter("ignore")
        if variant == "TorchScript exporter (dynamo=False)":
            f = io.BytesIO()
            torch.onnx.export(module, example, f, dynamo=False, opset_version=opset, input_names=list(names),
                              output_names=[output], dynamic_axes={n: {0: "batch", 2: "h", 3: "w"} for n in names})
            return onnx.load_from_string(f.getvalue())
        example = tuple(torch.cat([x, x]) for x in example) if example[0].shape[0] == 1 else example
        axes = {0: torch.export.Dim("batch", min=1, max=1024),
                2: torch.export.Dim("height", min=MIN_SIZE, max=MAX_SIZE),
                3: torch.export.Dim("width", min=MIN_SIZE, max=MAX_SIZE)}
        program = torch.onnx.export(module, example, dynamo=True, external_data=False, opset_version=opset,
                                    input_names=list(names), output_names=[output], optimize=False,
                                    dynamic_shapes=tuple(dict(axes) for _ in names))
        return program.model_proto


VARIANTS = ("as used (dynamo, optimised, dynamic size)", "without the onnxscript optimiser", "fixed frame size",
            "TorchScript exporter (dynamo=False)")


def _ort_ms(proto, names: tuple[str, ...], example: tuple, repeats: int = 5) -> float:
    from export.parity import ort_session

    session = ort_session(proto, threads=1)
    feed = {n: x.numpy() for n, x in zip(names, example)}
    session.run(None, feed)
    t = time.perf_counter()
    for _ in range(repeats):
        session.run(None, feed)
    return 1e3 * (time.perf_counter() - t) / repeats


def compare_variants(repeats: int) -> Callable:
    """An ``export_model`` stand-in that times :data:`VARIANTS` per graph and keeps the rows in ``RESULTS``."""
    import export.exporter as ex
    from export.parity import check_parity

    def variants(model, ckpt_path, output_dir, datamodule=None, *args, **kwargs) -> list:
        specs = ex.graph_specs(model)
        model.load_export_checkpoint(Path(ckpt_path))
        source = ex.parity_source(None, datamodule)
        images = ex.frames_from_source(source, ex.preprocessing_of(datamodule, source), 4)
        rows = {(s.kind, v): {"graph": s.kind, "variant": v, "seconds": [], "ort_ms": []}
                for s in specs for v in VARIANTS}
        for _ in range(repeats):
            for spec in specs:
                example = spec.example_inputs(images)
                for v in VARIANTS:
                    t = time.perf_counter()
                    proto = _export_variant(v, spec.module, example, spec.input_names, spec.output_name, spec.opset)
                    row = rows[(spec.kind, v)]
                    row["seconds"].append(time.perf_counter() - t)
                    row["nodes"] = len(proto.graph.node)
                    row["parity"] = check_parity(spec.module, proto, example, spec.input_names, 1e-3).max_abs_diff
                    row["ort_ms"].append(_ort_ms(proto, spec.input_names, example))
        RESULTS.extend(rows.values())
        return []
    return variants


RESULTS: list[dict] = []


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", type=Path, required=True, help="where the measurements go")
    ap.add_argument("--variants", type=int, default=0, help="compare the exporter variants, N times each")
    ap.add_argument("export_args", nargs=argparse.REMAINDER, help="-- then the options of `python -m c3f_models`")
    a = ap.parse_args(argv)
    args = a.export_args[1:] if a.export_args[:1] == ["--"] else a.export_args
    if a.variants:
        import export
        from c3f_models.cli import main as cli

        export.export_model = compare_variants(a.variants)
        cli(args)
        for row in RESULTS:
            row["median_seconds"] = statistics.median(row["seconds"])
        record = {"variants": RESULTS}
    else:
        record = {"steps": run_phases(args)}
    a.json.write_text(json.dumps(record, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
