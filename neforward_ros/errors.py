"""Exception hierarchy of neforward_ros.

Every error the package raises on bad input derives from :class:`NeforwardError`, so callers can
catch the package's errors without catching programming errors. The concrete classes also derive
from :class:`ValueError`, which is what a caller of a numerical library expects for bad values.
"""

from __future__ import annotations


class NeforwardError(Exception):
    """Base class of every error raised by neforward_ros."""


class ModelError(NeforwardError, ValueError):
    """The robot description cannot be turned into a model (malformed or unsupported URDF)."""


class InputError(NeforwardError, ValueError):
    """Joint-space input has the wrong shape, length or non-finite values."""
