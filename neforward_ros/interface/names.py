"""ROS 2 names for a node without ROS: namespaces, ``~``, remapping, and their DDS topic names.

Follows ROS 2's rules (design article "Topic and Service name mapping to DDS"): a relative name is
resolved in the node's namespace, ``~`` is the node's own name space (``/ns/node``), a remap rule
``from:=to`` replaces a name whose resolution equals the resolution of ``from``, and ROS 2 topic
``/a/b`` is DDS topic ``rt/a/b``.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field

from neforward_ros.errors import InputError

_TOKEN = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def is_token(text: str) -> bool:
    """Whether ``text`` can be one token of a ROS 2 name: letters, digits and _, not first a digit."""
    return _TOKEN.match(text) is not None


def _check(name: str, what: str) -> None:
    tokens = [t for t in name.strip("/").split("/") if t != "~"]
    if name.strip("/") and not all(is_token(t) for t in tokens):
        raise InputError(f"invalid ROS 2 {what} {name!r}: tokens are letters, digits and _, not starting with a digit")


@dataclass(frozen=True)
class NodeNames:
    """A node's name, namespace and remap rules; resolves topic names.

    Attributes:
        node_name: e.g. ``neforward``.
        namespace: absolute, e.g. ``/`` or ``/robot1``.
        remaps: ``from`` -> ``to`` as given after ``-r`` (either side may be relative).
    """

    node_name: str = "neforward"
    namespace: str = "/"
    remaps: Mapping[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        _check(self.node_name, "node name")
        if "/" in self.node_name:
            raise InputError(f"invalid ROS 2 node name {self.node_name!r}")
        namespace = "/" + self.namespace.strip("/")
        _check(namespace, "namespace")
        object.__setattr__(self, "namespace", namespace)
        for source, target in self.remaps.items():
            _check(source, "name in a remap rule")
            _check(target, "name in a remap rule")

    @property
    def fully_qualified_name(self) -> str:
        return self._join(self.namespace, self.node_name)

    def expand(self, name: str) -> str:
        """The fully qualified form of ``name`` (no remapping)."""
        _check(name, "topic name")
        if name.startswith("/"):
            return name.rstrip("/") or "/"
        if name == "~" or name.startswith("~/"):
            return self._join(self.fully_qualified_name, name[2:])
        return self._join(self.namespace, name)

    def resolve(self, name: str) -> str:
        """The fully qualified topic name after remapping."""
        expanded = self.expand(name)
        for source, target in self.remaps.items():
            if self.expand(source) == expanded:
                return self.expand(target)
        return expanded

    def dds_topic(self, name: str) -> str:
        """The DDS topic of a ROS 2 topic name: ``rt`` + the resolved name."""
        return "rt" + self.resolve(name)

    @staticmethod
    def _join(base: str, rest: str) -> str:
        return (base.rstrip("/") + "/" + rest.strip("/")).rstrip("/") or "/"
