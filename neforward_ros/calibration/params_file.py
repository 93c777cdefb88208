"""A ROS 2 params file from parameter values, in the form rcl reads: under ``/**`` (every node name
and namespace) and ``ros__parameters``, dotted names as nested mappings, doubles with a decimal point
(rcl reads ``1`` as an integer), and no empty list (rcl cannot type one)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from neforward_ros.parameters.table import PARAMETERS

_TYPES = {p.name: p.type for p in PARAMETERS}


def params_yaml(values: Mapping[str, Any], header: str = "") -> str:
    """The file's text: ``values`` by parameter name (the table's types decide how numbers are written)."""
    tree: dict[str, Any] = {}
    for name, value in values.items():
        if isinstance(value, (list, tuple)) and not value:
            continue
        node = tree
        parts = name.split(".")
        for part in parts[:-1]:
            node = node.setdefault(part, {})
        node[parts[-1]] = (_TYPES.get(name, ""), value)
    lines = [f"# {line}" if line else "#" for line in header.splitlines()]
    lines += ["/**:", "  ros__parameters:"]
    lines += _lines(tree, 4)
    return "\n".join(lines) + "\n"


def _lines(tree: Mapping[str, Any], indent: int) -> list[str]:
    out = []
    for key, entry in tree.items():
        if isinstance(entry, dict):
            out.append(" " * indent + f"{key}:")
            out += _lines(entry, indent + 2)
        else:
            kind, value = entry
            out.append(" " * indent + f"{key}: {_value(kind, value)}")
    return out


def _value(kind: str, value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_value(kind.rstrip("[]"), v) for v in value) + "]"
    if kind.startswith("double") or isinstance(value, float):
        number = float(value)
        if not math.isfinite(number):
            raise ValueError(f"not a finite number: {value!r}")
        text = repr(number)
        return text if any(c in text for c in ".en") else text + ".0"
    if isinstance(value, int):
        return str(value)
    return '"' + str(value).replace("\\", "\\\\").replace('"', '\\"') + '"'
