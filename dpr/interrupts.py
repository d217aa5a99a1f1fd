"""Ctrl-C that is never lost.

Python raises KeyboardInterrupt wherever the main thread is when SIGINT arrives. When that is inside a callback
that C code made into Python (pymunk calls Python when it frees a body), the exception is printed and dropped, and
the program runs on as if nothing happened. :func:`install` (done by the ``dpr`` command) keeps a note of every
Ctrl-C beside raising it, and :func:`raise_if_interrupted`, called at safe points (every step of an episode loop and
of training), raises it again there: a Ctrl-C that was dropped stops the work at the next step.

Nor may it be raised inside a wait on a lock: there it can leave the lock released twice, and Python then raises
RuntimeError("release unlocked lock") in place of the KeyboardInterrupt. :func:`wait_deferring_sigint` and
:func:`first_completed` wait in short slices and deliver a Ctrl-C between them.
"""

from __future__ import annotations

import concurrent.futures
import multiprocessing
import signal
import threading
from collections.abc import Callable, Collection, Iterator
from contextlib import contextmanager
from typing import TypeVar

_pending = False


def _on_sigint(signum, frame) -> None:
    global _pending
    _pending = True
    raise KeyboardInterrupt


def install() -> None:
    """Handle SIGINT by noting it and raising KeyboardInterrupt (the main thread only; elsewhere nothing)."""
    global _pending
    _pending = False
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, _on_sigint)


def raise_if_interrupted() -> None:
    """Raise KeyboardInterrupt if a Ctrl-C arrived since :func:`install` (once: the note is then cleared)."""
    global _pending
    if _pending:
        _pending = False
        raise KeyboardInterrupt


@contextmanager
def sigint_deferred() -> Iterator[None]:
    """Hold a Ctrl-C back until the block ends, then deliver it: for bookkeeping that must not be cut in half, and
    for waits on locks. Only the main thread can set signal handlers; elsewhere this does nothing."""
    if threading.current_thread() is not threading.main_thread() or signal.getsignal(signal.SIGINT) is None:
        yield
        return
    received: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: received.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if received:
        if callable(previous):
            previous(signal.SIGINT, None)  # Python's default handler raises KeyboardInterrupt
        elif previous == signal.SIG_DFL:
            signal.raise_signal(signal.SIGINT)


T = TypeVar("T")
WAIT_SLICE_S = 0.1  # how late a Ctrl-C may be delivered while a result is awaited


def wait_deferring_sigint(wait: Callable[[float], T]) -> T:
    """``wait(timeout)`` again and again until it returns rather than times out (TimeoutError, or
    multiprocessing's), with Ctrl-C held back during each wait and delivered between them."""
    while True:
        with sigint_deferred():
            try:
                return wait(WAIT_SLICE_S)
            except (TimeoutError, multiprocessing.TimeoutError):
                pass


def first_completed(futures: Collection[concurrent.futures.Future]) -> set[concurrent.futures.Future]:
    """The futures of ``futures`` that are done, once at least one is (``concurrent.futures.wait`` with
    FIRST_COMPLETED), with Ctrl-C delivered between waits."""

    def wait(timeout: float) -> set[concurrent.futures.Future]:
        done, _ = concurrent.futures.wait(futures, timeout, concurrent.futures.FIRST_COMPLETED)
        if not done:
            raise TimeoutError
        return done

    return wait_deferring_sigint(wait)
