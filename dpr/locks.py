"""One holder at a time for a folder that a long job writes (a dataset, a pipeline run folder): an advisory
``flock`` on a lock file that names the holder's process id.

The lock file exists only while it is held: :meth:`FolderLock.release` deletes it. A holder that died holds no
flock any more (the kernel drops it with the process), so its lock file is taken over by the next writer; deleting a
flocked file is safe because :meth:`FolderLock.acquire` checks, once it holds the lock, that the file it locked is
still the one at the path, and starts again when a releasing holder unlinked it in between."""

from __future__ import annotations

import fcntl
import os
from pathlib import Path


class LockHeld(RuntimeError):
    """Another live process holds the lock at ``path``; ``pid`` is its process id (None if it wrote none yet)."""

    def __init__(self, path: Path, pid: int | None):
        self.path, self.pid = path, pid
        holder = f"process {pid}" if pid is not None else "another process"
        super().__init__(f"{path}: {holder} is writing here; wait for it to finish or stop it")

    @property
    def holder(self) -> str:
        """`` (process N)`` to name the holder in a message, or nothing when it wrote no pid yet."""
        return f" (process {self.pid})" if self.pid is not None else ""


class FolderLock:
    """An exclusive ``flock`` on the file ``path``, which names the holder's pid while it is held."""

    def __init__(self, path: str | os.PathLike, wait: bool = False):
        self.path = Path(path)
        self.wait = wait  # acquire waits for the holder instead of raising LockHeld
        self.created = False  # whether this holder made the lock file (a dead holder may have left one)
        self._fd: int | None = None

    @property
    def held(self) -> bool:
        return self._fd is not None

    def acquire(self) -> None:
        """Take the lock, or raise :class:`LockHeld` naming the live holder's pid (unless ``wait``: then wait for
        it)."""
        while True:
            try:
                fd, created = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o644), True
            except FileExistsError:
                try:
                    fd, created = os.open(self.path, os.O_RDWR), False
                except FileNotFoundError:
                    continue  # its holder released it just now
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | (0 if self.wait else fcntl.LOCK_NB))
            except OSError:
                holder = _pid_in(fd)
                os.close(fd)
                raise LockHeld(self.path, holder) from None
            try:
                current = os.stat(self.path)
            except FileNotFoundError:
                current = None
            locked = os.fstat(fd)
            if current is None or (current.st_dev, current.st_ino) != (locked.st_dev, locked.st_ino):
                os.close(fd)  # the previous holder deleted the file we locked: lock the one there now
                continue
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
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

    def __enter__(self) -> FolderLock:
        self.acquire()
        return self

    def __exit__(self, *exc) -> None:
        self.release()


def _pid_in(fd: int) -> int | None:
    try:
        return int(os.pread(fd, 32, 0).decode().strip())
    except (OSError, ValueError):
        return None
