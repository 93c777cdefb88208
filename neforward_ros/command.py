"""The ``neforward`` executable's first module: Ctrl-C means "stop" from its first moment.

Until the command's own handling is in place (:func:`neforward_ros.cli.main`), a Ctrl-C ends the
process at once with the one line every interrupted command prints and exit code 130, instead of a
traceback from wherever the imports were. A SIGINT that the process inherited as ignored (a
background job of a non-interactive shell) stays ignored. The handler goes in through the builtin
``_signal`` (0.1 ms), not ``signal`` (1-1.5 ms: it builds its enums first), so that the moments
before it, when Python's own KeyboardInterrupt still applies, are as few as can be.
"""

import _signal
import os


def interrupted_early(signum: int, frame: object) -> None:
    os.write(2, b"neforward: interrupted\n")
    os._exit(130)


if _signal.getsignal(_signal.SIGINT) is not _signal.SIG_IGN:
    _signal.signal(_signal.SIGINT, interrupted_early)


def entry() -> None:
    """The ``neforward`` executable (``python -m neforward_ros`` too)."""
    from neforward_ros.cli import entry as run

    run()
