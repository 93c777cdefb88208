"""The ``--ros-args`` section of a ROS 2 node command line, read without ROS.

Supported: ``-r``/``--remap from:=to`` (``__ns`` and ``__node`` included), ``-p``/``--param
name:=value`` (the value read as YAML, as ROS 2 does), ``--params-file FILE`` and ``--log-level
LEVEL``. A ``node:`` prefix restricts a rule to that node name.

The no-ROS runtime reads its command line with this (``strict``: any other option is an error). The
rclpy node reads the same section before rcl does (not strict: rcl's other options are skipped), so
that both runtimes validate the same parameter files and ``-p`` values with the same messages.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import yaml

from neforward_ros.errors import InputError

# rcl options that take no value; every other rcl option takes one.
_FLAG_PREFIXES = ("--enable-", "--disable-")


@dataclass
class RosArgs:
    """What the ``--ros-args`` section said."""

    remaps: dict[str, str] = field(default_factory=dict)
    namespace: str | None = None
    node_name: str | None = None
    params: dict[str, Any] = field(default_factory=dict)
    params_files: list[str] = field(default_factory=list)
    log_level: str | None = None


def ros_args_section(argv: Sequence[str]) -> list[str]:
    """The tokens of every ``--ros-args ... [--]`` section of a whole command line."""
    out: list[str] = []
    inside = False
    for token in argv:
        if token == "--ros-args":
            inside = True
        elif token == "--" and inside:
            inside = False
        elif inside:
            out.append(token)
    return out


def parse_ros_args(arguments: Sequence[str], node_name: str, *, strict: bool = True) -> RosArgs:
    """Parse the tokens after ``--ros-args`` (up to an optional ``--``).

    Args:
        arguments: the tokens.
        node_name: the node's name before remapping: rules prefixed with another node's name are
            skipped.
        strict: raise on options other than the supported ones; otherwise skip them as rcl reads
            them (``--enable-*`` / ``--disable-*`` alone, any other with its value).

    Raises:
        InputError: an unsupported option (strict) or a malformed rule.
    """
    out = RosArgs()
    tokens = list(arguments)
    k = 0
    while k < len(tokens):
        option = tokens[k]
        if option == "--":
            break
        if option == "--ros-args":
            k += 1
            continue
        if not strict and option.startswith(_FLAG_PREFIXES):
            k += 1
            continue
        if k + 1 >= len(tokens):
            raise InputError(f"--ros-args: {option} needs a value")
        value = tokens[k + 1]
        k += 2
        if option in ("-r", "--remap"):
            source, target = _rule(value, node_name, "remap")
            if source is None:
                continue
            if source == "__ns":
                out.namespace = target
            elif source in ("__node", "__name"):
                out.node_name = target
            else:
                out.remaps[source] = target
        elif option in ("-p", "--param"):
            name, text = _rule(value, node_name, "param")
            if name is None:
                continue
            try:
                out.params[name] = yaml.safe_load(text) if text != "" else ""
            except yaml.YAMLError as exc:
                raise InputError(f"--ros-args -p {value}: value is not YAML: {exc}") from exc
        elif option == "--params-file":
            out.params_files.append(value)
        elif option == "--log-level":
            out.log_level = value.split(":")[-1].upper()
        elif strict:
            raise InputError(
                f"--ros-args: {option} is not supported here (supported: -r, -p, --params-file, --log-level)"
            )
    return out


def _rule(text: str, node_name: str, what: str) -> tuple[str | None, str]:
    if ":=" not in text:
        raise InputError(f"--ros-args {what} rule {text!r} is not of the form name:=value")
    left, right = text.split(":=", 1)
    if ":" in left:
        node, left = left.split(":", 1)
        if node != node_name:
            return None, right  # a rule for another node
    if not left:
        raise InputError(f"--ros-args {what} rule {text!r} has an empty name")
    return left, right
