"""Stamps: integer nanoseconds, as builtin_interfaces/Time carries them, and their conversions.

Everything that handles time stamps in neforward_ros keeps them as integer nanoseconds, so that
epoch-sized stamps (1.7e18 ns) keep nanosecond resolution, and converts to float seconds only
relative to a nearby origin.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from neforward_ros.errors import InputError

NS = 1_000_000_000
"""Nanoseconds per second."""

_INT32 = range(-(2**31), 2**31)


def split_stamp(stamp_ns: int) -> tuple[int, int]:
    """(sec, nanosec) of builtin_interfaces/Time from integer nanoseconds.

    Raises:
        InputError: a stamp outside builtin_interfaces/Time's range (int32 seconds).
    """
    sec, nanosec = divmod(int(stamp_ns), NS)
    if sec not in _INT32:
        raise InputError(f"stamp {stamp_ns} ns is outside the range of builtin_interfaces/Time (int32 seconds)")
    return sec, nanosec


def time_message(stamp_ns: int) -> dict[str, int]:
    """builtin_interfaces/Time contents from integer nanoseconds (see :func:`split_stamp`)."""
    sec, nanosec = split_stamp(stamp_ns)
    return {"sec": sec, "nanosec": nanosec}


def stamp_ns(time: Any) -> int:
    """Integer nanoseconds of a builtin_interfaces/Time (an object with sec and nanosec, or its dict)."""
    if isinstance(time, dict):
        return int(time["sec"]) * NS + int(time["nanosec"])
    return int(time.sec) * NS + int(time.nanosec)


def relative_seconds(stamps: Any) -> np.ndarray:
    """Stamps as float seconds since the first one.

    Integer input is taken as nanoseconds and subtracted exactly before conversion, so epoch-sized
    stamps (1.7e18 ns) keep nanosecond resolution; float input is taken as seconds.
    """
    t = np.asarray(stamps)
    if t.ndim != 1:
        raise InputError(f"stamps must be a 1-D array, got shape {t.shape}")
    if t.size == 0:
        return t.astype(float)
    if np.issubdtype(t.dtype, np.integer):
        return (t.astype(np.int64) - np.int64(t[0])).astype(float) * 1e-9
    try:
        t = t.astype(float)
    except (TypeError, ValueError) as exc:
        raise InputError(f"stamps are not numbers: {exc}") from exc
    return t - t[0]
