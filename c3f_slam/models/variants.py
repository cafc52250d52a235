"""The keypoint descriptors file of the same export beside a dense one.

An export of ContraFeat writes the dense map graph (``contrafeat.onnx``) and the keypoint graph
(``contrafeat_kp.onnx``) into one folder with ``export.json``. Given the dense file, the runtime
uses the keypoint file instead (the same descriptors without the full-resolution map) when it is
of the same export: ``export.json`` beside the dense file lists both, the keypoint file is listed
with ``descriptor_sampling: keypoints`` and its SHA-256 matches the listing, and its metadata
records the same checkpoint (SHA-256), pre-processing, descriptor dimension and precision. Otherwise the
dense file is used and :func:`keypoint_file_beside` says why.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

from c3f_core.errors import InputError
from c3f_slam.models.metadata import ModelMetadata
from c3f_slam.models.session import DEFAULT_PROVIDERS, OnnxModel
from c3f_slam.models.zoo import sha256_of

#: the manifest an export writes beside its files
MANIFEST = "export.json"


def _listed_keypoint_file(dense: Path) -> tuple[Path | None, dict, str]:
    """(path, export.json entry) of the keypoint file the export of ``dense`` lists, or
    (None, {}, why not)."""
    manifest = dense.parent / MANIFEST
    if not manifest.is_file():
        return None, {}, f"no {MANIFEST} beside {dense.name}"
    try:
        files = json.loads(manifest.read_text(encoding="utf-8")).get("files") or {}
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, AttributeError):
        return None, {}, f"{MANIFEST} is unreadable"
    if not isinstance(files, dict) or dense.name not in files:
        return None, {}, f"{MANIFEST} does not list {dense.name}"
    names = [n for n, e in files.items() if isinstance(e, dict) and e.get("kind") == "descriptors"
             and e.get("descriptor_sampling") == "keypoints"]
    if not names:
        return None, {}, f"{MANIFEST} lists no keypoint descriptors file"
    path = dense.parent / names[0]
    if not path.is_file():
        return None, {}, f"{names[0]}, listed in {MANIFEST}, is missing"
    return path, files[names[0]], ""


def _differences(kp: ModelMetadata, dense: ModelMetadata) -> str:
    """What makes the keypoint file's metadata not that of the dense file's export ("" if nothing)."""
    if kp.sampling != "keypoints":
        return "its metadata is not descriptor_sampling keypoints"
    if not kp.checkpoint.get("sha256") or kp.checkpoint.get("sha256") != dense.checkpoint.get("sha256"):
        return "it records another checkpoint (SHA-256)"
    if kp.preprocessing != dense.preprocessing or kp.descriptor_dim != dense.descriptor_dim:
        return "its pre-processing or descriptor dimension differs"
    if kp.precision != dense.precision:
        return f"its precision ({kp.precision}) is not the dense file's ({dense.precision})"
    return ""


def keypoint_file_beside(dense: Path, metadata: ModelMetadata, threads: int = 2, option: str | None = None,
                         providers: Sequence[str] = DEFAULT_PROVIDERS) -> tuple[OnnxModel | None, str]:
    """The opened keypoint file (on ``providers``) of the export of the dense descriptors file
    ``dense`` (with ``metadata``), or None and why not (one line)."""
    path, entry, why = _listed_keypoint_file(Path(dense))
    if path is None:
        return None, why
    if sha256_of(path) != entry.get("sha256"):
        return None, f"{path.name} does not match its SHA-256 in {MANIFEST}"
    try:
        model = OnnxModel(path, expect_kind="descriptors", threads=threads, option=option, providers=providers)
    except InputError as exc:
        return None, f"{path.name} cannot be used ({exc})"
    differs = _differences(model.metadata, metadata)
    return (None, f"{path.name}: {differs}") if differs else (model, "used")


__all__ = ["MANIFEST", "keypoint_file_beside"]
