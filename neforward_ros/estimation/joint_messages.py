"""One joint-state message's fields, checked: which samples it gives, or why it gives none.

The rules every runtime and the bag tool apply (bad input is never raised, it is dropped and said,
throttled):

- ``name`` and ``position`` of different lengths: the message is rejected.
- a name given twice: the message is rejected (which of two values is right cannot be told).
- a name the model lacks: ignored; said once per set of names, in one line with the count and a
  few examples (a message of 20,000 unknown names is one line, not 20,000). Mimic joints, which
  follow their leader, are ignored silently.
- a non-finite position: that joint's sample is dropped (the others are used).
- ``velocity`` or ``effort`` of the wrong length: that field is ignored; non-finite entries are
  dropped from it.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from neforward_ros.logs import ThrottledLog

Sample = tuple[int, float, float, float]
"""(joint index, position, velocity or NaN, effort or NaN)."""

EXAMPLES = 3
"""Names quoted in a line about unknown names."""


@dataclass(frozen=True)
class NameMap:
    """A message's names against the joints.

    Attributes:
        pairs: (position in the message, joint index) of the known names, in message order.
        unknown: the names that are neither joints nor ignored, in message order.
        duplicate: a name given more than once, or None.
    """

    pairs: tuple[tuple[int, int], ...]
    unknown: tuple[str, ...]
    duplicate: str | None


def name_map(names: Sequence[str], index: Mapping[str, int], ignored: frozenset[str] = frozenset()) -> NameMap:
    """A message's names against ``index`` (joint name -> joint index); ``ignored`` are known to be
    neither (mimic joints)."""
    pairs = []
    unknown = []
    for k, name in enumerate(names):
        j = index.get(name)
        if j is not None:
            pairs.append((k, j))
        elif name not in ignored:
            unknown.append(name)
    duplicate = None
    if len(set(names)) != len(names):
        seen: set[str] = set()
        duplicate = next(name for name in names if name in seen or seen.add(name))  # type: ignore[func-returns-value]
    return NameMap(tuple(pairs), tuple(unknown), duplicate)


def describe_names(names: Iterable[str], what: str = "names") -> str:
    """'3 names: a, b, c' or '20000 names: a, b, c and 19997 more' (a bounded line)."""
    names = list(names)
    shown = ", ".join(repr(n) for n in names[:EXAMPLES])
    more = f" and {len(names) - EXAMPLES} more" if len(names) > EXAMPLES else ""
    return f"{len(names)} {what if len(names) != 1 else what.rstrip('s')}: {shown}{more}"


class JointMessageReader:
    """Checks joint-state messages against a model's joints (see the module docstring).

    Args:
        joint_names: the joints, in index order.
        ignored_names: names that are not joints and not unknown either (mimic joints).
        log: where problems are said, throttled.
        use_velocities: False ignores every message velocity (``velocity_source: differentiate``).
    """

    KEPT = 64  # name lists remembered (a driver sends one or two; bounded against a flood of new ones)

    def __init__(
        self, joint_names: Sequence[str], ignored_names: Iterable[str], log: ThrottledLog, use_velocities: bool = True
    ) -> None:
        self._names = tuple(joint_names)
        self._index = {name: i for i, name in enumerate(joint_names)}
        self._ignored = frozenset(ignored_names)
        self._log = log
        self._use_velocities = use_velocities
        self._maps: dict[tuple[str, ...], NameMap] = {}
        self._reported: set[int] = set()

    def names(self, names: Sequence[str]) -> NameMap:
        """The message's names mapped (kept for the last name lists seen), unknown ones reported."""
        key = tuple(names)
        found = self._maps.get(key)
        if found is None:
            found = name_map(key, self._index, self._ignored)
            if len(self._maps) >= self.KEPT:
                del self._maps[next(iter(self._maps))]
            self._maps[key] = found
            self.report_unknown(found.unknown)
        return found

    def report_unknown(self, unknown: Sequence[str]) -> None:
        """One line per new set of unknown names (throttled with the other lines of its kind)."""
        if not unknown:
            return
        signature = hash(tuple(unknown))
        if signature in self._reported or len(self._reported) > 4096:
            return
        self._reported.add(signature)
        self._log.every(
            "unknown-names",
            logging.WARNING,
            f"joint states name {describe_names(unknown, 'joints')} that the model does not have: ignored",
        )

    def read(
        self, names: Sequence[str], positions: Sequence[float], velocities: Sequence[float], efforts: Sequence[float]
    ) -> list[Sample] | None:
        """The message's usable samples; None rejects it (said, throttled)."""
        count = len(names)
        if len(positions) != count:
            self._log.every(
                "length", logging.WARNING, f"joint state rejected: {count} names but {len(positions)} positions"
            )
            return None
        mapped = self.names(names)
        if mapped.duplicate is not None:
            self._log.every(
                "duplicate",
                logging.WARNING,
                f"joint state rejected: it names joint {mapped.duplicate!r} more than once (which value is right "
                "cannot be told)",
            )
            return None
        if not mapped.pairs:
            return []
        position = self._floats(positions, "positions", count)
        if position is None:
            return None
        velocity = self._floats(velocities, "velocities", count) if len(velocities) and self._use_velocities else None
        if velocity is None:
            velocity = [math.nan] * count
        elif not math.isfinite(sum(velocity)):
            self._log.every(("nan", "velocities"), logging.WARNING, "joint state with non-finite velocities: dropped")
            velocity = [v if math.isfinite(v) else math.nan for v in velocity]
        effort = self._floats(efforts, "efforts", count) if len(efforts) else None
        if effort is None:
            effort = [math.nan] * count
        elif not math.isfinite(sum(effort)):
            self._log.every(("nan", "efforts"), logging.WARNING, "joint state with non-finite efforts: dropped")
            effort = [e if math.isfinite(e) else math.nan for e in effort]
        if math.isfinite(sum(position)):  # the usual case: every position is a number (inf - inf is NaN)
            return [(j, position[k], velocity[k], effort[k]) for k, j in mapped.pairs]
        samples = []
        dropped = []
        for k, j in mapped.pairs:
            if math.isfinite(position[k]):
                samples.append((j, position[k], velocity[k], effort[k]))
            else:
                dropped.append(self._names[j])
        self._log.every(
            "nan-position",
            logging.WARNING,
            f"joint state with a non-finite position of {describe_names(dropped, 'joints')}: those samples dropped",
        )
        return samples

    def _floats(self, values: Sequence[float], what: str, count: int) -> list[float] | None:
        """A message field as floats; None (said) when it is of the wrong length or not numbers."""
        if len(values) != count:
            self._log.every(
                ("length", what), logging.WARNING, f"joint state {what} ignored: {len(values)} values for {count} names"
            )
            return None
        try:
            if isinstance(values, np.ndarray) and values.dtype.kind == "f":
                return values.tolist()
            return [float(v) for v in values]
        except (TypeError, ValueError):
            self._log.every(("type", what), logging.WARNING, f"joint state {what} are not numbers: ignored")
            return None
