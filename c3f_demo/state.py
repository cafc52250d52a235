"""Which stages of a demo folder are done, with which inputs, and the settings of its last run:
``DIR/demo_state.json`` (``config``: the whole :class:`~c3f_demo.config.DemoConfig` as a mapping,
which ``python -m c3f_demo --config DIR/demo_state.json`` replays).

A stage's key is the SHA-256 of its settings and the keys of the stages it reads from, so a
changed setting invalidates that stage and every stage after it. A rerun skips a stage whose
key matches; a stage recorded with another key is refused (one line) unless ``overwrite``. The
runner forgets a stage and every stage that reads from it before the stage runs.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from c3f_core.atomic import atomic_write_text
from c3f_core.errors import InputError

STATE_FILE = "demo_state.json"
STATE_VERSION = 1


def stage_key(settings: dict, upstream: list[str]) -> str:
    """Hex SHA-256 of a stage's settings (JSON, sorted keys) and its upstream stages' keys."""
    text = json.dumps({"settings": settings, "upstream": upstream}, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


class DemoState:
    """The state file of one demo folder: per stage its key, seconds and result notes."""

    def __init__(self, root: Path, overwrite: bool = False, config: dict | None = None) -> None:
        """``config``: the run's settings (a mapping), written with the stages (default: the file's)."""
        self.root, self.overwrite = Path(root), overwrite
        self.path = self.root / STATE_FILE
        self.stages: dict[str, dict] = {}
        self.config, replay = config, ""
        if self.path.is_file():
            try:
                data = json.loads(self.path.read_text())
            except (OSError, ValueError) as exc:
                raise InputError(f"{self.path}: unreadable demo state ({exc}); use another --out") from None
            self.stages = dict(data.get("stages", {}))
            replay = f" (--config {self.path} replays the last run's)" if data.get("config") else ""
            self.config = config if config is not None else data.get("config")
        elif self.root.is_dir() and any(self.root.iterdir()):
            raise InputError(f"--out {self.root}: not empty and not a demo folder (no {STATE_FILE}); "
                             "choose another --out")
        self._replay = replay

    def is_done(self, name: str, key: str) -> bool:
        """True when ``name`` finished with ``key``; InputError when it finished with another key
        (unless ``overwrite``: then False, and the runner redoes it)."""
        rec = self.stages.get(name)
        if rec is None:
            return False
        if rec.get("key") == key:
            return True
        if not self.overwrite:
            raise InputError(f"--out {self.root}: stage {name} was made with other settings (e.g. with/without "
                             f"--quick); rerun with the same options{self._replay}, pass --overwrite to redo it, "
                             "or choose another --out")
        return False

    def forget(self, names: list[str]) -> None:
        """Drop the records of ``names`` (a stage about to run and the stages that read from it)."""
        gone = [n for n in names if n in self.stages]
        for n in gone:
            del self.stages[n]
        if gone:
            self.save()

    def record(self, name: str, key: str, seconds: float, notes: dict | None = None) -> None:
        self.stages[name] = {"key": key, "seconds": round(seconds, 2), "notes": notes or {}}
        self.save()

    def notes(self, name: str) -> dict:
        return self.stages.get(name, {}).get("notes", {})

    def save(self) -> None:
        self.root.mkdir(parents=True, exist_ok=True)
        data = {"version": STATE_VERSION, **({"config": self.config} if self.config is not None else {}),
                "stages": self.stages}
        atomic_write_text(self.path, json.dumps(data, indent=2) + "\n")
