"""The dataset's files as a whole: the one-writer lock and the removal of crash leftovers."""

from __future__ import annotations

import fcntl
import os
from pathlib import Path

from dpr.atomic import TMP_SUFFIX
from dpr.datasets.lerobot.format import CHUNK_FILE_RE, CHUNKS_SIZE, LOCK_PATH, DatasetError


class WriterLock:
    """An advisory ``flock`` on ``meta/.dpr-writer.lock``: one writer per dataset at a time."""

    def __init__(self, root: Path):
        self.path = root / LOCK_PATH
        self._fd: int | None = None

    @property
    def held(self) -> bool:
        return self._fd is not None

    def acquire(self) -> None:
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            raise DatasetError(f"{self.path}: another writer holds this dataset open") from None
        self._fd = fd

    def release(self) -> None:
        if self._fd is not None:
            os.close(self._fd)  # closing drops the flock
            self._fd = None


def delete_leftovers(root: Path, total_episodes: int, referenced: set[Path]) -> None:
    """Remove temp files and the data/meta files of episodes >= total_episodes (never a referenced file)."""
    for folder in (root / "data", root / "meta"):
        if not folder.is_dir():
            continue
        for path in folder.rglob(f"*{TMP_SUFFIX}"):
            path.unlink(missing_ok=True)
    for base in (root / "data", root / "meta" / "episodes"):
        if not base.is_dir():
            continue
        for path in base.glob("*/*.parquet"):
            match = CHUNK_FILE_RE.match(f"{path.parent.name}/{path.name}")
            if match is None or path.resolve() in referenced:
                continue
            if int(match.group(1)) * CHUNKS_SIZE + int(match.group(2)) >= total_episodes:
                path.unlink()
