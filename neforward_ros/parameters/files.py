"""Parameter values from a node's command line and its ROS 2 params files, by rcl's rules."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from neforward_ros.errors import InputError
from neforward_ros.parameters.ros_args import RosArgs, parse_ros_args
from neforward_ros.parameters.table import NODE_NAME


def node_name_matches(key: str, fully_qualified_name: str) -> bool:
    """Whether a params-file key names this node, by rcl's rules.

    A key without a leading ``/`` is taken from the root (``neforward`` is ``/neforward``, which a
    node in namespace ``/robot1`` does not match); ``*`` matches one name token and ``**`` any number,
    so ``/**`` matches every node and ``/**/neforward`` a node called neforward in any namespace.
    """
    pattern = [t for t in key.strip().strip("/").split("/") if t]
    name = [t for t in fully_qualified_name.strip("/").split("/") if t]

    def match(p: int, n: int) -> bool:
        if p == len(pattern):
            return n == len(name)
        if pattern[p] == "**":
            return any(match(p + 1, m) for m in range(n, len(name) + 1))
        return n < len(name) and pattern[p] in ("*", name[n]) and match(p + 1, n + 1)

    return match(0, 0)


def load_params_file(path: str | Path, node_name: str = NODE_NAME, namespace: str = "/") -> dict[str, Any]:
    """Parameter values for a node from a ROS 2 params file.

    The file maps node names to ``ros__parameters``; the entries that name this node by rcl's rules
    (see :func:`node_name_matches`) apply, in file order. Nested mappings give dotted names
    (``estimator: {window: 0.2}`` is ``estimator.window``).

    Raises:
        InputError: the file is missing or is not such YAML.
    """
    import yaml

    try:
        document = yaml.safe_load(Path(path).read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise InputError(f"cannot read params file {path}: {exc}") from exc
    if not isinstance(document, dict):
        raise InputError(f"params file {path} is not a mapping of node names to ros__parameters")
    fully_qualified = namespace.rstrip("/") + "/" + node_name
    values: dict[str, Any] = {}
    for key, entry in document.items():
        if not node_name_matches(str(key), fully_qualified):
            continue
        if not isinstance(entry, dict) or not isinstance(entry.get("ros__parameters"), dict):
            raise InputError(f"params file {path}: {key} has no ros__parameters mapping")
        values.update(_flatten(entry["ros__parameters"]))
    return values


def command_line_parameters(
    tokens: Sequence[str], *, strict: bool = True, params_file: str | None = None
) -> tuple[RosArgs, dict[str, Any]]:
    """The ``--ros-args`` section of a node command line and the parameter values it gives.

    Values come from the params files in order (``params_file`` first when given), then ``-p``
    rules. Both runtimes call this, so a file or value is accepted or rejected alike by both.

    Raises:
        InputError: a malformed section or an unreadable params file.
    """
    parsed = parse_ros_args(tokens, NODE_NAME, strict=strict)
    node_name = parsed.node_name or NODE_NAME
    namespace = parsed.namespace or "/"
    values: dict[str, Any] = {}
    for path in [*([params_file] if params_file else []), *parsed.params_files]:
        values.update(load_params_file(path, node_name, namespace))
    values.update(parsed.params)
    return parsed, values


def _flatten(mapping: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in mapping.items():
        if isinstance(value, dict):
            out.update(_flatten(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def joint_numbers(items: Sequence[str], option: str, width: int = 1) -> dict[str, list[float]]:
    """Command-line JOINT=V (or V,W with width 2) items (``--hold``, ``--effort``, ``--effort-scale`` ...)
    as joint -> numbers.

    Raises:
        InputError: an item that is not JOINT=NUMBER (or JOINT=NUMBER[,NUMBER]), naming ``option``.
    """
    out = {}
    for item in items:
        name, _, value = item.partition("=")
        try:
            numbers = [float(v) for v in value.split(",")]
        except ValueError:
            numbers = []
        if not name.strip() or not 1 <= len(numbers) <= width:
            shape = "JOINT=NUMBER" if width == 1 else "JOINT=NUMBER[,NUMBER]"
            raise InputError(f"{option} takes {shape}, got {item!r}")
        out[name.strip()] = numbers
    return out
