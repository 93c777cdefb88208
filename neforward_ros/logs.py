"""Logging for transport-free code: an injectable log function, once-only and throttled messages.

The core never imports rclpy or a DDS library. It logs through a plain function
``log(level, message)``, where level is a :mod:`logging` level (``logging.WARNING``, ...). Each runtime
passes its own: the rclpy adapter maps it to the node's logger, and the default is a Python
:class:`logging.Logger`. Bad input that repeats at the message rate is throttled here, per kind of
problem, so a broken driver cannot flood the log.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Hashable

LogFunction = Callable[[int, str], None]
"""``log(level, message)`` with a :mod:`logging` level."""

DEFAULT_THROTTLE_PERIOD = 5.0
"""Seconds between two messages of the same kind."""


def python_log(name: str = "neforward_ros") -> LogFunction:
    """A log function writing to the Python logger ``name``."""
    return logging.getLogger(name).log


class ThrottledLog:
    """Once-only and rate-limited messages, keyed by the kind of problem.

    Args:
        log: where messages go; the Python logger ``neforward_ros`` by default.
        period: seconds between two messages with the same key (``every``).
        clock: monotonic seconds; injectable for tests.
    """

    def __init__(
        self,
        log: LogFunction | None = None,
        period: float = DEFAULT_THROTTLE_PERIOD,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._log = log if log is not None else python_log()
        self._period = period
        self._clock = clock
        self._said: set[Hashable] = set()
        self._last: dict[Hashable, float] = {}
        self._suppressed: dict[Hashable, int] = {}

    def log(self, level: int, message: str) -> None:
        """Log unconditionally."""
        self._log(level, message)

    def once(self, key: Hashable, level: int, message: str) -> bool:
        """Log ``message`` the first time ``key`` is seen, never again. Returns whether it was logged."""
        if key in self._said:
            return False
        self._said.add(key)
        self._log(level, message)
        return True

    def every(self, key: Hashable, level: int, message: str | Callable[[], str]) -> bool:
        """Log at most once per period for ``key``, saying how many were suppressed in between.
        ``message`` may be a function that makes it: called only when the line is written (a check
        that fails at every message costs no formatting)."""
        now = self._clock()
        last = self._last.get(key)
        if last is not None and now - last < self._period:
            self._suppressed[key] = self._suppressed.get(key, 0) + 1
            return False
        skipped = self._suppressed.pop(key, 0)
        self._last[key] = now
        text = message() if callable(message) else message
        self._log(level, f"{text} ({skipped} more like this since the last report)" if skipped else text)
        return True


class BoundedLog:
    """A log function that writes at most ``rate`` lines per second on average, in bursts of up to
    ``burst`` (a token bucket): the runtimes wrap their log in it, so that no input, however broken and
    however varied, makes the node write more than a few lines per second, on top of the throttling
    of each kind of problem. Lines over the bound are counted and the count said with the next line.

    Args:
        log: where lines go.
        rate: lines per second in the long run.
        burst: lines at once (start-up says a few things).
        clock: monotonic seconds; injectable for tests.
    """

    def __init__(
        self, log: LogFunction, rate: float = 2.0, burst: int = 30, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self._log = log
        self._rate = rate
        self._burst = float(burst)
        self._tokens = float(burst)
        self._clock = clock
        self._last = clock()
        self.suppressed = 0

    def __call__(self, level: int, message: str) -> None:
        now = self._clock()
        self._tokens = min(self._burst, self._tokens + (now - self._last) * self._rate)
        self._last = now
        if self._tokens < 1.0:
            self.suppressed += 1
            return
        self._tokens -= 1.0
        if self.suppressed:
            message = f"{message} ({self.suppressed} lines left out before this one: the log is kept short)"
            self.suppressed = 0
        self._log(level, message)
