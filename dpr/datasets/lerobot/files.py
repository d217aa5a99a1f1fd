"""The dataset's files as a whole: the one-writer lock and the removal of leftovers (of crashes and compactions)."""

from __future__ import annotations

import fcntl
import os
import re
from pathlib import Path

from dpr.atomic import TMP_SUFFIX
from dpr.datasets.lerobot.format import LOCK_PATH, DatasetError, file_number, in_threads

CHUNK_DIR_RE = re.compile(r"^chunk-\d{3,}$")


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


def remove_file(path: Path) -> None:
    """Delete one leftover file (a seam for tests that stop a clean-up half way)."""
    path.unlink(missing_ok=True)


def delete_leftovers(root: Path, live: tuple[int, int], referenced: set[Path] = frozenset()) -> int:
    """Remove temp files and every numbered data/meta file outside the live numbers ``[first, end)`` (files of
    uncommitted episodes, or the side of a compaction that is not live), never a file in ``referenced``; then
    the chunk folders left empty. Returns the number of files removed."""
    first, end = live
    doomed: list[Path] = []
    for folder in (root / "data", root / "meta"):
        if folder.is_dir():
            doomed.extend(folder.rglob(f"*{TMP_SUFFIX}"))
    bases = [base for base in (root / "data", root / "meta" / "episodes") if base.is_dir()]
    for base in bases:
        for path in sorted(base.glob("*/*.parquet")):
            number = file_number(path)
            if number is not None and not first <= number < end and path.resolve() not in referenced:
                doomed.append(path)
    in_threads(remove_file, doomed)
    for base in bases:
        for chunk in base.iterdir():
            if chunk.is_dir() and CHUNK_DIR_RE.match(chunk.name) and not any(chunk.iterdir()):
                chunk.rmdir()
    return len(doomed)
