"""The dataset's files as a whole: the one-writer lock and the removal of crash leftovers."""

from __future__ import annotations

import fcntl
import os
from pathlib import Path

from dpr.atomic import TMP_SUFFIX
from dpr.datasets.lerobot.format import CHUNK_FILE_RE, CHUNKS_SIZE, LOCK_PATH, DatasetError


class WriterLock:
    """An advisory ``flock`` on ``meta/.dpr-writer.lock``: one writer per dataset at a time.

    The lock file exists only while a writer holds it: :meth:`release` deletes it (a finished dataset holds no lock
    file). Deleting a flocked file is safe because :meth:`acquire` checks, once it holds the lock, that the file it
    locked is still the one at the path, and starts again when a releasing writer unlinked it in between."""

    def __init__(self, root: Path):
        self.path = root / LOCK_PATH
        self.created = False  # whether this writer made the lock file (a crashed writer may have left one)
        self._fd: int | None = None

    @property
    def held(self) -> bool:
        return self._fd is not None

    def acquire(self) -> None:
        while True:
            try:
                fd, created = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o644), True
            except FileExistsError:
                try:
                    fd, created = os.open(self.path, os.O_RDWR), False
                except FileNotFoundError:
                    continue  # its holder released it just now
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                os.close(fd)
                raise DatasetError(f"{self.path}: another writer holds this dataset open") from None
            try:
                current = os.stat(self.path)
            except FileNotFoundError:
                current = None
            locked = os.fstat(fd)
            if current is None or (current.st_dev, current.st_ino) != (locked.st_dev, locked.st_ino):
                os.close(fd)  # the previous holder deleted the file we locked: lock the one there now
                continue
            self._fd, self.created = fd, created
            return

    def release(self, *, remove: bool = True) -> None:
        """Drop the lock; ``remove`` also deletes the lock file (while still holding it, so no one locks a file
        about to vanish)."""
        if self._fd is None:
            return
        try:
            if remove:
                self.path.unlink(missing_ok=True)
        finally:
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
