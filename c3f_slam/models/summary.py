"""Human-readable report of an export's metadata (``python -m c3f_slam inspect MODEL.onnx``)."""

from __future__ import annotations

import json
from typing import Any

from c3f_slam.models.metadata import ModelMetadata

MAX_CONFIG_LINES = 24


def _flatten(d: Any, prefix: str = "") -> list[tuple[str, Any]]:
    if isinstance(d, dict) and d:
        out: list[tuple[str, Any]] = []
        for k in sorted(d):
            out += _flatten(d[k], f"{prefix}.{k}" if prefix else str(k))
        return out
    return [(prefix, d)]


def _short(v: Any, width: int = 80) -> str:
    text = v if isinstance(v, str) else json.dumps(v, sort_keys=True)
    return text if len(text) <= width else text[: width - 3] + "..."


def _shape(s: Any) -> str:
    return "(" + ", ".join(str(v) for v in s) + ")" if isinstance(s, (list, tuple)) else str(s)


def _num(v: Any) -> str:
    return f"{v:.6g}" if isinstance(v, (int, float)) and not isinstance(v, bool) else str(v)


def _io_line(d: dict) -> str:
    units = f" [{d['units']}]" if d.get("units") else ""
    return f"    {d.get('name')}{units}: {_shape(d.get('shape'))} {d.get('dtype', '')}  {d.get('meaning', '')}".rstrip()


def _parity_line(par: dict) -> str:
    """The parity entry in one line: the bounded number first (max |diff|, or for a float16 or
    int8 graph the mean |diff| relative to the mean output magnitude)."""
    where = f"tolerance {par.get('tolerance')}, {par.get('frames')} frames"
    if par.get("criterion") == "relative_mean":
        return (f"  parity:          mean |diff| / mean |output| {_num(par.get('relative_mean_diff'))} ({where}; "
                f"max |diff| {_num(par.get('max_abs_diff'))}) against PyTorch float32")
    return f"  parity:          max |diff| {par.get('max_abs_diff')} ({where})"


def format_metadata(meta: ModelMetadata, source: str = "model") -> str:
    """Multi-line report: kind, input size, inputs/outputs with units, pre-processing, depth
    range, descriptor dim, training-config summary, checkpoint hash, parity, provenance."""
    pp = meta.preprocessing
    w, h = meta.input_size
    lines = [
        f"{source}",
        f"  kind:            {meta.kind}",
        f"  precision:       {meta.precision}{'' if meta.precision == 'float32' else ' (float32 inputs and outputs)'}",
        f"  input size:      {w}x{h} (width x height){', any size accepted' if meta.dynamic_size else ''}"
        f"{', dynamic batch' if meta.dynamic_batch else ''}",
        "  inputs:",
    ]
    for i in meta.inputs:
        lines.append(_io_line(i))
    lines.append("  outputs:")
    for o in meta.outputs:
        lines.append(_io_line(o))
    crop = f"{pp.crop[0]}x{pp.crop[1]}" if pp.crop else "none"
    spec = (f"on (luma > {pp.specular_threshold}, {pp.specular_dilation_px} px dilation, Telea)"
            if pp.specular_inpaint else "off")
    norm = "inside the graph" if pp.normalization_in_graph else "NOT in the graph"
    lines += [
        "  preprocessing:",
        f"    centre crop:   {crop}, then resize to {w}x{h}",
        f"    specular:      {spec}",
        f"    input:         {pp.input_range}; ImageNet normalisation {norm}",
        f"                   (mean {list(pp.mean)}, std {list(pp.std)})",
    ]
    if meta.depth:
        d = meta.depth
        lines.append(f"  depth range:     {_num(d.get('min_depth'))} .. {_num(d.get('max_depth'))} m"
                     f"{'; ' + _short(d['conversion']) if d.get('conversion') else ''}")
        if d.get("metric_scale") is not None:
            lines.append(f"  metric scale:    x {_num(d.get('metric_scale'))} to metres (training data, "
                         f"{d.get('metric_scale_frames', '?')} frames, spread {_num(d.get('metric_scale_spread'))}); "
                         "applied by c3f_slam run unless --depth-scale")
    if meta.descriptor_dim is not None:
        per = ("per keypoint; sampled at the given keypoints inside the graph" if meta.sampling == "keypoints"
               else "per pixel")
        lines.append(f"  descriptor dim:  {meta.descriptor_dim} (unit norm {per})")
    cfg = _flatten(meta.training_config) if meta.training_config else []
    lines.append(f"  training config: {'none recorded' if not cfg else f'{len(cfg)} settings'}")
    for k, v in cfg[:MAX_CONFIG_LINES]:
        lines.append(f"    {k}: {_short(v)}")
    if len(cfg) > MAX_CONFIG_LINES:
        lines.append(f"    ... {len(cfg) - MAX_CONFIG_LINES} more")
    ck = meta.checkpoint
    lines.append(f"  checkpoint:      {ck.get('file', 'unknown')} sha256 {ck.get('sha256', 'unknown')}" if ck
                 else "  checkpoint:      not recorded")
    par = meta.parity
    lines.append(_parity_line(par) if par else "  parity:          not recorded")
    ds = par.get("dense_sampling") if isinstance(par, dict) else None
    if isinstance(ds, dict):
        lines.append(f"                   vs the dense graph sampled at the same keypoints: max |diff| "
                     f"{ds.get('max_abs_diff')} (tolerance {ds.get('tolerance')}, {ds.get('keypoints')} keypoints)")
    lines.append(f"  export:          opset {meta.opset}, c3fusion {meta.project_version}, "
                 f"created {meta.created or 'unknown'}, metadata schema {meta.schema_version}")
    return "\n".join(lines)
