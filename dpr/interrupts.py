"""Ctrl-C that is never lost.

Python raises KeyboardInterrupt wherever the main thread is when SIGINT arrives. When that is inside a callback
that C code made into Python (pymunk calls Python when it frees a body), the exception is printed and dropped, and
the program runs on as if nothing happened. :func:`install` (done by the ``dpr`` command) keeps a note of every
Ctrl-C beside raising it, and :func:`raise_if_interrupted`, called at safe points (every step of an episode loop and
of training), raises it again there: a Ctrl-C that was dropped stops the work at the next step.
"""

from __future__ import annotations

import signal
import threading

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
