"""The model zoo: trained models shipped in the repository's ``zoo/`` folder, loaded by name.

Every option that takes a model file also takes ``zoo:NAME`` (``--depth-model zoo:NAME``,
``--feature-model zoo:NAME``, ``--model.init_weights zoo:NAME``). An entry is a folder
``zoo/NAME/`` holding its files and a model card, ``README.md``, in the Hugging Face
convention: YAML front matter (licence, data, metrics) and then the text. The project's own
part of the front matter, under ``c3fusion``, is machine-readable::

    c3fusion:
      kind: depth                 # or descriptors
      files:                      # file name -> role, SHA-256, bytes
        depthnet.onnx: {role: depth, sha256: ..., bytes: ...}
        weights.safetensors: {role: weights, sha256: ..., bytes: ...}
      model: {class_path: ..., init_args: {...}}   # what the weights fit
      metrics: {...}              # the held-out numbers of the card

Roles: ``depth``, ``pose``, ``descriptors`` (ONNX exports, as ``python -m c3f_models export``
writes them) and ``weights`` (float16 safetensors of the LightningModule's state dict, for
test-time training and fine-tuning). A file is used only when its SHA-256 matches the card.

The zoo folder is ``zoo/`` beside the packages, or the folder named by ``C3F_ZOO``. Nothing is
ever downloaded. This module needs no torch.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from pathlib import Path

import yaml

from c3f_core.errors import InputError

PREFIX = "zoo:"
ENV = "C3F_ZOO"
CARD = "README.md"
KINDS = ("depth", "descriptors")
#: what each entry kind provides: the roles its card must list
ROLES = {"depth": ("depth", "weights"), "descriptors": ("descriptors", "weights")}
#: the kind of entry each role comes from
ROLE_KIND = {"depth": "depth", "pose": "depth", "descriptors": "descriptors"}


def zoo_root() -> Path:
    """The zoo folder: ``$C3F_ZOO`` if set, else ``zoo/`` at the repository's root."""
    env = os.environ.get(ENV)
    return Path(env) if env else Path(__file__).resolve().parents[2] / "zoo"


def is_zoo_name(value: object) -> bool:
    return isinstance(value, str) and value.startswith(PREFIX)


def sha256_of(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def split_card(text: str, where: str) -> tuple[dict, str]:
    """(front matter as a dict, the body) of a model card's text."""
    if not text.startswith("---\n"):
        raise InputError(f"{where}: no YAML front matter (the card must start with a '---' line)")
    end = text.find("\n---\n", 4)
    if end < 0:
        raise InputError(f"{where}: the front matter has no closing '---' line")
    try:
        meta = yaml.safe_load(text[4:end])
    except yaml.YAMLError as exc:
        raise InputError(f"{where}: front matter is not valid YAML ({str(exc).splitlines()[0]})") from None
    if not isinstance(meta, dict):
        raise InputError(f"{where}: front matter is not a mapping")
    return meta, text[end + 5:]


@dataclass(frozen=True)
class ZooFile:
    name: str
    role: str
    sha256: str
    bytes: int


@dataclass(frozen=True)
class ZooEntry:
    """One entry of the zoo, as its card describes it."""

    name: str
    folder: Path
    meta: dict  #: the whole front matter

    @property
    def own(self) -> dict:
        return self.meta.get("c3fusion") or {}

    @property
    def kind(self) -> str:
        return str(self.own.get("kind"))

    @property
    def files(self) -> dict[str, ZooFile]:
        out = {}
        for fname, spec in (self.own.get("files") or {}).items():
            spec = spec or {}
            out[fname] = ZooFile(fname, str(spec.get("role")), str(spec.get("sha256")), int(spec.get("bytes", 0)))
        return out

    @property
    def metrics(self) -> dict:
        return self.own.get("metrics") or {}

    @property
    def summary(self) -> str:
        return str(self.own.get("summary", ""))

    def file_for(self, role: str, option: str, kind: str | None = None) -> Path:
        """The verified path of the file with ``role``; InputError naming ``option`` when this entry
        is of another kind (``kind``; default: the role's), lacks the file, or the file's SHA-256
        differs from the card's."""
        wanted = kind or ROLE_KIND.get(role)
        if wanted is not None and self.kind != wanted:
            raise InputError(f"{option}: {PREFIX}{self.name} is a {self.kind} model, expected a {wanted} model")
        matches = [f for f in self.files.values() if f.role == role]
        if not matches:
            raise InputError(f"{option}: {PREFIX}{self.name} has no {role} file (its card lists "
                             f"{', '.join(sorted(self.files)) or 'none'})")
        return self.verify(matches[0], option)

    def verify(self, entry: ZooFile, option: str) -> Path:
        path = self.folder / entry.name
        if not path.is_file():
            raise InputError(f"{option}: {PREFIX}{self.name}: {path} is missing (listed in its card)")
        digest = sha256_of(path)
        if digest != entry.sha256:
            raise InputError(f"{option}: {PREFIX}{self.name}: {path} does not match its card (SHA-256 "
                             f"{digest[:12]}..., card {entry.sha256[:12]}...); refused")
        return path


def read_entry(folder: Path, option: str = "zoo") -> ZooEntry:
    """The entry in ``folder`` (its card checked for the fields every entry needs)."""
    card = folder / CARD
    if not card.is_file():
        raise InputError(f"{option}: {folder} has no model card ({CARD})")
    meta, _ = split_card(card.read_text(encoding="utf-8"), str(card))
    entry = ZooEntry(folder.name, folder, meta)
    if entry.kind not in KINDS:
        raise InputError(f"{option}: {card}: c3fusion.kind must be one of {', '.join(KINDS)}, got {entry.kind}")
    for f in entry.files.values():
        if len(f.sha256) != 64:
            raise InputError(f"{option}: {card}: file {f.name} has no SHA-256 in the card")
    return entry


def entries(root: Path | None = None) -> list[ZooEntry]:
    """Every entry of the zoo (folders with a card), sorted by name."""
    root = zoo_root() if root is None else root
    if not root.is_dir():
        return []
    return [read_entry(p) for p in sorted(root.iterdir()) if (p / CARD).is_file()]


def entry(name: str, option: str = "zoo", root: Path | None = None) -> ZooEntry:
    """The entry called ``name`` (with or without the ``zoo:`` prefix); InputError listing the
    names there are when it does not exist."""
    name = name[len(PREFIX):] if name.startswith(PREFIX) else name
    root = zoo_root() if root is None else root
    folder = root / name
    if not name or "/" in name or name.startswith(".") or not (folder / CARD).is_file():
        known = ", ".join(e.name for e in entries(root)) or "none"
        raise InputError(f"{option}: {PREFIX}{name}: no such zoo model in {root} (there are: {known})")
    return read_entry(folder, option)


def resolve(value: str | Path, role: str, option: str) -> Path:
    """A model option's value as a file path: ``zoo:NAME`` becomes the entry's verified file of
    ``role``; anything else is returned as a path, unchanged."""
    if is_zoo_name(value):
        return entry(str(value), option).file_for(role, option)
    return Path(value)


__all__ = ["CARD", "ENV", "PREFIX", "ZooEntry", "ZooFile", "entries", "entry", "is_zoo_name", "resolve",
           "split_card", "zoo_root"]
