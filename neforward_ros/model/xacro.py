"""Whether a description needs xacro, and expanding it with the xacro package when it does.

A file is xacro when it *uses* xacro where the robot is described, not when it merely declares the
namespace: files that xacro generated keep ``xmlns:xacro`` on ``<robot>`` (Panda, PR2, Baxter, the UR
grippers, ANYmal ... in example-robot-data), and are plain URDF. It needs xacro when, outside the
elements urdfdom ignores, it has an element in the xacro namespace other than a ``property`` or
``arg`` definition (``xacro:include``, ``xacro:macro``, ``xacro:if``, a macro call), or a ``${...}``
or ``$(...)`` in a link's or joint's attributes or text. xacro markup left over where urdfdom does
not look (inside ``<gazebo>`` or ``<transmission>``, unused property definitions) is ignored, as
urdfdom ignores it, and said once.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from neforward_ros.errors import ModelError
from neforward_ros.model.document import children

NAMESPACE_MARK = "ros.org/wiki/xacro"
"""What every xacro namespace URI holds (www.ros.org, ros.org, wiki.ros.org; with or without a slash or #)."""
_DEFINITIONS = ("property", "arg")
_READ = ("link", "joint")  # what urdfdom reads of <robot>'s children


@dataclass(frozen=True)
class XacroUse:
    """What xacro markup a description has: ``needed`` names the first use that only xacro can resolve
    (None: none), ``leftover`` the first piece of markup that can be ignored (None: none)."""

    needed: str | None
    leftover: str | None


def _xacro_name(tag: str, prefixes: set[str]) -> str | None:
    """The local name of an element in the xacro namespace (``xacro:include`` -> ``include``), else None.
    lxml names a declared namespace's element ``{uri}name``, and keeps an undeclared prefix as written."""
    if tag.startswith("{"):
        uri, _, name = tag[1:].partition("}")
        return name if NAMESPACE_MARK in uri else None
    prefix, colon, name = tag.partition(":")
    return name if colon and prefix in prefixes else None


def _shown(element: Any, prefixes: set[str]) -> str:
    name = _xacro_name(element.tag, prefixes)
    return f"<{'xacro:' + name if name else element.tag}> at line {element.sourceline}"


def _substitution(element: Any) -> str | None:
    """The first ``${`` or ``$(`` in the element's or its descendants' attributes or text."""
    for node in element.iter():
        for name, value in node.attrib.items():
            if "${" in value or "$(" in value:
                return f'{name}="{value}" at line {node.sourceline}'
        text = node.text or ""
        if "${" in text or "$(" in text:
            return f"{text.strip()[:60]!r} at line {node.sourceline}"
    return None


def xacro_use(root: Any) -> XacroUse:
    """The xacro markup of a description (see the module docstring); ``root`` an lxml element."""
    prefixes = {"xacro"} | {p for p, uri in root.nsmap.items() if p and uri and NAMESPACE_MARK in uri}
    for element in root.iter():  # declarations below the root
        prefixes |= {p for p, uri in element.nsmap.items() if p and uri and NAMESPACE_MARK in uri}

    needed = leftover = None
    for child in children(root):
        name = _xacro_name(child.tag, prefixes)
        if name is not None:
            if name in _DEFINITIONS:
                leftover = leftover or _shown(child, prefixes)
            else:
                needed = needed or _shown(child, prefixes)
        elif child.tag in _READ:
            for node in child.iter():
                if _xacro_name(node.tag, prefixes) is not None:
                    needed = needed or _shown(node, prefixes)
            substitution = _substitution(child)
            if substitution is not None:
                needed = needed or substitution
        elif leftover is None:
            markup = next((_shown(n, prefixes) for n in child.iter() if _xacro_name(n.tag, prefixes)), None)
            leftover = markup or _substitution(child)
    if leftover is None:  # <robot name="${name}">: urdfdom takes the name as it is
        leftover = next(
            (f'{k}="{v}" at line {root.sourceline}' for k, v in root.attrib.items() if "${" in v or "$(" in v), None
        )
    return XacroUse(needed, leftover)


def expand(path: str) -> bytes:
    """The URDF a xacro file expands to (with the xacro package, as ROS 2 launch files do).

    Raises:
        ModelError: the xacro package is missing (the message says how to install it or expand the
            file by hand), or xacro cannot expand the file.
    """
    try:
        import xacro
    except ImportError as exc:
        raise ModelError(
            f"{path} is a xacro file: install xacro to read it directly (pip install xacro), "
            f"or expand it first: xacro {path} > robot.urdf"
        ) from exc
    try:
        return xacro.process_file(path).toxml().encode("utf-8")
    except BaseException as exc:  # xacro raises its own errors, and SystemExit on some
        if isinstance(exc, KeyboardInterrupt):
            raise
        raise ModelError(f"xacro could not expand {path}: {exc}") from exc
