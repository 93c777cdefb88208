"""The terminal's standard error line: whether a progress bar left it unfinished, so that a message
written next (an error, "interrupted") starts on a line of its own."""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from typing import TextIO

_open = False


def line_left_open(is_open: bool) -> None:
    """Say whether the last thing written to standard error ended without a newline."""
    global _open
    _open = is_open


def say(message: str, stream: TextIO | None = None) -> None:
    """Write a line to standard error, after ending a line a progress bar left open."""
    stream = stream if stream is not None else sys.stderr
    if _open:
        stream.write("\n")
        line_left_open(False)
    print(message, file=stream)
