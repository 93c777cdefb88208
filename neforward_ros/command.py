"""The ``neforward`` executable's first module: Ctrl-C means "stop" from its first moment.

Until the command's own handling is in place (:func:`neforward_ros.cli.main`), a Ctrl-C ends the
process at once with the one line every interrupted command prints and exit code 130, instead of a
traceback from wherever the imports were. A SIGINT that the process inherited as ignored (a
background job of a non-interactive shell) stays ignored.
"""

import os
import signal


def interrupted_early(signum: int, frame: object) -> None:
    os.write(2, b"neforward: interrupted\n")
    os._exit(130)


if signal.getsignal(signal.SIGINT) is not signal.SIG_IGN:
    signal.signal(signal.SIGINT, interrupted_early)


def entry() -> None:
    """The ``neforward`` executable (``python -m neforward_ros`` too)."""
    from neforward_ros.cli import entry as run

    run()
