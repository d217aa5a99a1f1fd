"""Crash-safe file writes: the one helper behind every writer (LeRobot, MCAP, rerun, run configs).

A file is written under a temporary name beside its target, flushed and fsynced, then renamed over the target,
and the folder is fsynced so that the rename itself survives a power cut. A reader therefore sees the old file
or the whole new one, never a torn one. Temporary names end in :data:`TMP_SUFFIX` and start with a dot, so that
LeRobot's ``*.parquet`` globs and ``ls`` both pass them by.
"""

from __future__ import annotations

import hashlib
import json
import os
import secrets
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

TMP_SUFFIX = ".dpr-tmp"


def fsync_dir(folder: str | os.PathLike) -> None:
    """Make renames inside ``folder`` durable (a file's own fsync does not cover its directory entry).
    Best effort where the platform cannot open a folder."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def is_temporary(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a temporary file left by an interrupted :class:`AtomicFile`."""
    return Path(path).name.endswith(TMP_SUFFIX)


class AtomicFile:
    """A binary file that appears at ``path`` only when :meth:`commit` succeeds.

    ``exclusive=True`` refuses to replace a file that already exists at ``path`` (checked when opening and
    again when committing, with a hard link, which fails if the target exists). :meth:`abort` (also called by
    ``with`` on an exception) deletes the temporary file and leaves ``path`` as it was.
    """

    def __init__(self, path: str | os.PathLike, *, exclusive: bool = False, sync_folder: bool = True):
        self.path = Path(path)
        self.exclusive = exclusive
        self.sync_folder = sync_folder
        if exclusive and self.path.exists():
            raise FileExistsError(f"{self.path} already exists")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0)
        while True:
            self.temp_path = self.path.with_name(f".{self.path.name}.{os.getpid()}.{secrets.token_hex(4)}{TMP_SUFFIX}")
            try:
                fd = os.open(self.temp_path, flags, 0o666)  # the umask, not mkstemp's 0600, sets permissions
            except FileExistsError:
                continue
            break
        self.file: IO[bytes] = os.fdopen(fd, "wb")
        self.done = False

    def commit(self) -> Path:
        """Flush, fsync and rename the temporary file onto ``path``; returns ``path``."""
        if self.done:
            raise ValueError(f"{self.path}: already committed or aborted")
        try:
            self.file.flush()
            os.fsync(self.file.fileno())
            self.file.close()
            if self.exclusive:
                os.link(self.temp_path, self.path)  # fails if a file appeared at path meanwhile
                os.unlink(self.temp_path)
            else:
                os.replace(self.temp_path, self.path)
        except BaseException:
            self.abort()
            raise
        self.done = True
        if self.sync_folder:
            fsync_dir(self.path.parent)
        return self.path

    def abort(self) -> None:
        """Delete the temporary file; ``path`` is left as it was."""
        self.done = True
        try:
            self.file.close()
        finally:
            self.temp_path.unlink(missing_ok=True)

    def __enter__(self) -> AtomicFile:
        return self

    def __exit__(self, exc_type, exc, traceback) -> None:
        if exc_type is not None:
            if not self.done:
                self.abort()
        elif not self.done:
            self.commit()


def atomic_write(
    path: str | os.PathLike, write: Callable[[IO[bytes]], Any], *, exclusive: bool = False, sync_folder: bool = True
) -> Path:
    """Call ``write(file)`` on a temporary file, then commit it onto ``path`` (see :class:`AtomicFile`).
    ``sync_folder=False`` when a later write in the same folder fsyncs it before anything depends on this one."""
    with AtomicFile(path, exclusive=exclusive, sync_folder=sync_folder) as target:
        write(target.file)
    return target.path


def atomic_write_bytes(path: str | os.PathLike, data: bytes, **options: Any) -> Path:
    return atomic_write(path, lambda f: f.write(data), **options)


def atomic_write_text(path: str | os.PathLike, text: str, **options: Any) -> Path:
    return atomic_write_bytes(path, text.encode("utf-8"), **options)


def atomic_write_json(path: str | os.PathLike, obj: Any, *, indent: int | None = 4, **options: Any) -> Path:
    return atomic_write_text(path, json.dumps(obj, indent=indent, ensure_ascii=False) + "\n", **options)


def atomic_write_parquet(
    path: str | os.PathLike, table: Any, *, write_options: dict | None = None, **options: Any
) -> Path:
    """Write a pyarrow ``table`` as parquet through :class:`AtomicFile`; ``write_options`` go to
    ``pyarrow.parquet.write_table`` (compression, use_dictionary, ...), ``options`` to :func:`atomic_write`."""
    import pyarrow.parquet as pq  # lazy: only the dataset writers need pyarrow

    return atomic_write(path, lambda f: pq.write_table(table, f, **(write_options or {})), **options)


def atomic_link(source: str | os.PathLike, path: str | os.PathLike, *, sync_folder: bool = True) -> Path:
    """Give the finished, durable file ``source`` a second name ``path`` (a hard link: no bytes copied; a copy
    through :func:`atomic_write` where the filesystem has no hard links), replacing any file at ``path``: a reader
    of ``path`` sees the old file or the whole of ``source``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    temp_path = path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}{TMP_SUFFIX}")
    try:
        os.link(source, temp_path)
    except OSError:  # no hard links on this filesystem
        with open(source, "rb") as original:
            return atomic_write(path, lambda f: shutil.copyfileobj(original, f, 1 << 20), sync_folder=sync_folder)
    try:
        os.replace(temp_path, path)
    except BaseException:
        temp_path.unlink(missing_ok=True)
        raise
    if sync_folder:
        fsync_dir(path.parent)
    return path


def file_sha256(path: Path) -> str:
    """The SHA-256 of the file at ``path`` (hex), read in blocks: what records and model cards
    compare a file against to know it is the one written."""
    digest = hashlib.sha256()
    with open(path, "rb") as file:
        for block in iter(lambda: file.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()
