"""What a run of ``neforward bag`` did, said on the terminal: the report and the progress bar."""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from typing import Any

from neforward_ros import terminal
from neforward_ros.stamps import NS


@dataclass
class Segment:
    """A stretch of the recording whose stamps increase; estimated on its own."""

    first_ns: int
    last_ns: int
    messages: int
    samples_out: int = 0
    skipped: int = 0
    partial: int = 0
    note: str = ""


@dataclass
class BagReport:
    """What a run did."""

    joint_states_topic: str
    messages: int
    samples_out: int = 0
    segments: list[Segment] = field(default_factory=list)
    zero_stamps: int = 0
    ignored_names: str = ""  # a bounded line: the count and a few examples
    segment_starts: Any = ()  # indices of the messages (as kept) that begin a new segment
    missing_joints: list[str] = field(default_factory=list)
    held: dict[str, float] = field(default_factory=dict)  # the missing joints' held positions
    contacts: list[tuple[float, float | None]] = field(default_factory=list)  # s since the first joint state
    notes: list[str] = field(default_factory=list)
    topics: list[str] = field(default_factory=list)
    written: dict[str, int] = field(default_factory=dict)  # messages per output topic
    seconds: float = 0.0


class Progress:
    """A progress bar on stderr, drawn only when stderr is a terminal."""

    def __init__(self, enabled: bool | None = None) -> None:
        self.enabled = sys.stderr.isatty() if enabled is None else enabled
        self._last = 0.0
        self._finished = ""

    def __call__(self, what: str, fraction: float) -> None:
        """Draw stage ``what`` at ``fraction`` (0 to 1); a stage's 100 % line is drawn once."""
        if not self.enabled or what == self._finished:
            return
        now = time.monotonic()
        if fraction < 1.0 and now - self._last < 0.1:
            return
        self._last = now
        filled = int(30 * min(max(fraction, 0.0), 1.0))
        terminal.line_left_open(True)  # first: an interrupt while writing must still end the line
        sys.stderr.write(f"\r{what:<12} [{'#' * filled}{'.' * (30 - filled)}] {100 * fraction:5.1f}%")
        terminal.line_left_open(fraction < 1.0)
        if fraction >= 1.0:
            sys.stderr.write("\n")
            self._finished = what
        sys.stderr.flush()


def describe(report: BagReport) -> str:
    """The report as a few lines for the terminal."""
    got = {topic: report.written.get(topic, 0) for topic in report.topics}
    lines = [
        f"{report.messages} joint states from {report.joint_states_topic}; {report.samples_out} stamps with output, "
        f"in {report.seconds:.1f} s; messages written: {', '.join(f'{t} {n}' for t, n in got.items() if n)}",
    ]
    empty = [topic for topic, n in got.items() if not n]
    if empty:
        lines.append(
            f"nothing written to {', '.join(empty)}: no stamp had what they need (torques and contact: every joint's "
            "estimate; external torques: measured efforts too)"
        )
    if len(report.segments) > 1:
        lines.append(
            f"{len(report.segments)} segments (time went back between them and went on from there), each estimated "
            "on its own:"
        )
    for number, segment in enumerate(report.segments, 1):
        span = (segment.last_ns - segment.first_ns) / NS
        note = f"; {segment.skipped} stamps without output" if segment.skipped else ""
        if segment.partial:
            note += f"; {segment.partial} with only some links (joints without an estimate)"
        if segment.note:
            note += f"; {segment.note}"
        lines.append(f"  segment {number}: {segment.messages} messages over {span:.3f} s{note}")
    if report.zero_stamps:
        lines.append(
            f"{report.zero_stamps} messages had a zero header.stamp (none had one): their recording time was used"
        )
    for start, end in report.contacts:
        until = f"to {end:.3f} s" if end is not None else "to the end"
        lines.append(f"contact: from {start:.3f} s {until} (since the first joint state)")
    lines.extend(report.notes)
    if report.missing_joints:
        held = ", ".join(f"{name} at {position:g}" for name, position in report.held.items())
        lines.append(
            f"warning: joints of the model never in the recording, held at rest ({held}): set their positions with "
            "--hold NAME=VALUE (hold.joint_names, hold.positions)"
        )
    if report.ignored_names:
        lines.append(f"ignored, not joints of the model: {report.ignored_names}")
    return "\n".join(lines)
