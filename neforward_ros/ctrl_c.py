"""Ctrl-C as a command's KeyboardInterrupt: never lost in a finalizer, and taken, not acted on, once
the command's work is done.

Python turns SIGINT into a KeyboardInterrupt wherever the main thread happens to be. That can be a
finalizer (a ``weakref.finalize`` run as an object is freed, a ``__del__``, a weakref callback), where
Python can only print the exception with a traceback and go on: the interrupt would be lost, and a
run would end done (exit status 0) with a traceback on the terminal. So:

- while a command runs (:func:`acted_on`), a KeyboardInterrupt that ends in a finalizer is not printed
  but raised again in the main thread's next ordinary line, as a new Ctrl-C would be;
- once its outputs are in place (:func:`hold`), SIGINT is ignored; the executable keeps it so until it
  exits.

A library can also turn the KeyboardInterrupt into another error or swallow it: a C extension whose
import it lands in (2026-11-30: in CI, one in matplotlib's came out as an ImportError, the run ended on
"--plot needs matplotlib" and the interpreter crashed at exit; here, one in lxml's was swallowed and the
run went on to finish). So the executable's handler (:func:`interrupt`) remembers that a
Ctrl-C came: the command counts any error after it as the interrupt (:func:`came`), and a long command
acts on one swallowed at its next step (:func:`check`).

:func:`release` puts back what these changed (a command run in-process, by a test calling
:func:`neforward_ros.cli.main`).
"""

from __future__ import annotations

import _thread
import signal
import sys
import threading
from collections.abc import Callable
from typing import Any

_handler: list[Any] = []  # the SIGINT handler put aside by hold(), while it holds
_hook: list[Any] = []  # the unraisable hook put aside by acted_on(), while it is in place
_came: list[bool] = []  # [True] once interrupt() ran


def interrupt(signum: int, frame: object) -> None:
    """SIGINT's handler while the executable runs a command: Python's own (KeyboardInterrupt), and the
    Ctrl-C remembered."""
    _came[:] = [True]
    raise KeyboardInterrupt


def came() -> bool:
    """Whether :func:`interrupt` ran: the command was interrupted, whatever a library made of it."""
    return bool(_came)


def check() -> None:
    """KeyboardInterrupt if a Ctrl-C came (one that a library swallowed is acted on here), until the
    command's work is done (:func:`hold`)."""
    if _came and not _handler:
        raise KeyboardInterrupt


def checking(progress: Callable[[str, float], None]) -> Callable[[str, float], None]:
    """``progress``, calling :func:`check` first: a long command's steps are where it stops."""

    def step(stage: str, fraction: float) -> None:
        check()
        progress(stage, fraction)

    return step


def _unraisable(unraisable: Any) -> None:
    """sys.unraisablehook: a KeyboardInterrupt met in a finalizer goes to the main thread again."""
    if isinstance(unraisable.exc_value, KeyboardInterrupt):
        # From another thread: in this one, the interrupt would come up at once, inside this hook. The
        # main thread takes it at its next line (in another finalizer, it comes here again); where
        # SIGINT is ignored by then (held), it does nothing.
        try:
            _thread.start_new_thread(_thread.interrupt_main, (signal.SIGINT,))
        except RuntimeError:  # no new thread at the interpreter's shutdown: the command is over
            pass
        return
    (_hook[0] if _hook else sys.__unraisablehook__)(unraisable)


def acted_on() -> None:
    """From now on a KeyboardInterrupt met in a finalizer is raised again instead of printed."""
    if not _hook:
        _hook.append(sys.unraisablehook)
        sys.unraisablehook = _unraisable


def hold() -> None:
    """From now on SIGINT is ignored (in the main thread only, where handlers can change; once)."""
    if threading.current_thread() is threading.main_thread() and not _handler:
        _handler.append(signal.signal(signal.SIGINT, signal.SIG_IGN))


def release() -> None:
    """What :func:`acted_on` and :func:`hold` changed, put back."""
    if _handler and threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, _handler.pop())
    if _hook:
        sys.unraisablehook = _hook.pop()
    _came.clear()
