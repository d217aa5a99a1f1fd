"""The dataset's files as a whole: the one-writer lock and the removal of leftovers (of crashes and compactions)."""

from __future__ import annotations

import re
from pathlib import Path

from dpr.atomic import TMP_SUFFIX
from dpr.datasets.lerobot.format import LOCK_PATH, DatasetError, file_number, in_threads
from dpr.locks import FolderLock, LockHeld

CHUNK_DIR_RE = re.compile(r"^chunk-\d{3,}$")


class WriterLock(FolderLock):
    """The one-writer lock of a dataset, ``meta/.dpr-writer.lock`` (:class:`dpr.locks.FolderLock`): a finished
    dataset holds no lock file; a second writer gets a :class:`DatasetError` naming the holder's pid."""

    def __init__(self, root: Path):
        super().__init__(root / LOCK_PATH)

    def acquire(self) -> None:
        try:
            super().acquire()
        except LockHeld as held:
            raise DatasetError(
                f"{self.path}: another writer{held.holder} holds this dataset open for writing"
            ) from None


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
