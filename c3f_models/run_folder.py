"""A refused run leaves no run folder behind: what it created is removed, nothing else.

Lightning makes the logger's folder (``tb/version_N`` with an events file) and the CLI saves
``config.yaml`` into it before the model's ``setup`` can refuse the run (a bad
``--model.init_weights``, a data folder without training sequences, ...). :class:`RunFolderGuard`
notes what existed before the run; :meth:`RunFolderGuard.roll_back` removes the files and
folders that appeared since, puts back a ``config.yaml`` the run replaced (a resumed run writes
into its checkpoint's folder), and removes the parent folders it created if they are empty.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass, field
from pathlib import Path

CONFIG_NAME = "config.yaml"


@dataclass
class RunFolderGuard:
    """What a run's log folder ``folder`` held before the run (nothing when it did not exist)."""

    folder: Path
    existed: set[Path] = field(default_factory=set)
    config: bytes | None = None
    created_parents: list[Path] = field(default_factory=list)

    @classmethod
    def before(cls, folder: str | Path | None) -> RunFolderGuard | None:
        """The state of ``folder`` now (None: the run has no log folder)."""
        if folder is None:
            return None
        folder = Path(folder).absolute()
        parents = []
        for parent in folder.parents:
            if parent.exists():
                break
            parents.append(parent)
        existed = set(folder.rglob("*")) | {folder} if folder.exists() else set()
        config = folder / CONFIG_NAME
        return cls(folder, existed, config.read_bytes() if config.is_file() else None, parents)

    def roll_back(self) -> None:
        """Remove what appeared under the folder since :meth:`before` (the folder too if it is new)."""
        if not self.folder.exists():
            return
        if not self.existed:
            shutil.rmtree(self.folder, ignore_errors=True)
        else:
            new = sorted((p for p in self.folder.rglob("*") if p not in self.existed), key=lambda p: -len(p.parts))
            for path in new:
                if path.is_dir() and not path.is_symlink():
                    shutil.rmtree(path, ignore_errors=True)
                else:
                    path.unlink(missing_ok=True)
            if self.config is not None:
                (self.folder / CONFIG_NAME).write_bytes(self.config)
        for parent in self.created_parents:  # nearest first
            try:
                parent.rmdir()
            except OSError:
                break


__all__ = ["CONFIG_NAME", "RunFolderGuard"]
