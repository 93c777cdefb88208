"""Ctrl-C once a command's work is done: taken, not acted on.

Python turns SIGINT into a KeyboardInterrupt wherever the main thread happens to be. Once a
command's outputs are in place, that can be a finalizer (a ``weakref.finalize`` run as the model is
freed, a ``__del__``), where Python can only print the exception with a traceback and go on: the run
would end done, with exit status 0, and a traceback on the terminal. :func:`hold` ignores SIGINT from
that moment; the executable keeps it so until it exits, and a command run in-process (a test calling
:func:`neforward_ros.cli.main`) gets its handler back with :func:`release`.
"""

from __future__ import annotations

import signal
import threading
from typing import Any

_held: list[Any] = []  # the SIGINT handler put aside by hold(), while it holds


def hold() -> None:
    """From now on SIGINT is ignored (in the main thread only, where handlers can change; once)."""
    if threading.current_thread() is threading.main_thread() and not _held:
        _held.append(signal.signal(signal.SIGINT, signal.SIG_IGN))


def release() -> None:
    """The SIGINT handler that :func:`hold` put aside, back in place (nothing if it holds nothing)."""
    if _held and threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, _held.pop())
