"""The sequences of a batch: a folder of converted sequences or videos, or a list file.

A folder: each sub-folder (not hidden) is a sequence folder and each video file in it a video
(``c3f_slam.frames.stream.VIDEO_SUFFIXES``), in name order. A list file (any other file): one sequence
folder or video per line, relative to the list file's folder unless absolute; blank lines and
``#`` comments are ignored. An entry that does not exist stays in the batch: its run fails with
its own one-line error, the others go on. Each sequence gets a run folder name, unique in the
batch: its folder or file name without the video suffix (``_2``, ``_3``, ... after a repeat).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from c3f_core.errors import InputError

#: files a batch writes into its output folder, never taken for a run folder's name
RESERVED_NAMES = frozenset({"batch.json", "batch.csv", "index.html"})


@dataclass(frozen=True)
class BatchItem:
    """One sequence of a batch: its run folder's ``name`` and its ``source`` (folder or video)."""

    name: str
    source: Path


def _video_suffixes() -> tuple[str, ...]:
    from c3f_slam.frames.stream import VIDEO_SUFFIXES  # OpenCV: only once a batch runs

    return VIDEO_SUFFIXES


def _sources_in_folder(folder: Path) -> list[Path]:
    videos = _video_suffixes()
    found = [p for p in sorted(folder.iterdir()) if not p.name.startswith(".")
             and (p.is_dir() or p.suffix.lower() in videos)]
    if not found:
        raise InputError(f"{folder}: holds no sequence folder and no video ({', '.join(videos)})")
    return found


def _sources_in_list(path: Path) -> list[Path]:
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: the list of sequences cannot be read ({exc})") from None
    entries = [line.split("#", 1)[0].strip() for line in lines]
    found = [p if p.is_absolute() else path.parent / p for p in (Path(e) for e in entries if e)]
    if not found:
        raise InputError(f"{path}: the list of sequences names none (one folder or video per line)")
    return found


def _name(source: Path, taken: set[str]) -> str:
    base = source.stem if source.suffix.lower() in _video_suffixes() else source.name
    base = base or "sequence"
    name, k = base, 1
    while name in taken or name in RESERVED_NAMES:
        k += 1
        name = f"{base}_{k}"
    taken.add(name)
    return name


def find_items(dataset: str | Path) -> list[BatchItem]:
    """The sequences of ``dataset`` (a folder or a list file), each with its run folder name.
    InputError naming ``dataset`` when it is missing or names no sequence."""
    path = Path(dataset)
    if not path.exists():
        raise InputError(f"{path}: no such folder or list file")
    sources = _sources_in_folder(path) if path.is_dir() else _sources_in_list(path)
    taken: set[str] = set()
    return [BatchItem(_name(s, taken), s) for s in sources]


__all__ = ["RESERVED_NAMES", "BatchItem", "find_items"]
