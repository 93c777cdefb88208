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

from neforward_ros.errors import ModelError
from neforward_ros.model.xml_tree import Element

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


def _prefixes(root: Element) -> set[str]:
    """Element-name prefixes bound to the xacro namespace anywhere in the document, and ``xacro``."""
    found = {"xacro"}
    for element in root.iter():
        for name, value in element.attrib.items():
            if name.startswith("xmlns:") and NAMESPACE_MARK in value:
                found.add(name[len("xmlns:") :])
    return found


def _substitution(element: Element) -> str | None:
    """The first ``${`` or ``$(`` in the element's or its descendants' attributes or text."""
    for node in element.iter():
        for name, value in node.attrib.items():
            if "${" in value or "$(" in value:
                return f'{name}="{value}" at line {node.line}'
        if "${" in node.text or "$(" in node.text:
            return f"{node.text.strip()[:60]!r} at line {node.line}"
    return None


def xacro_use(root: Element) -> XacroUse:
    """The xacro markup of a description (see the module docstring)."""
    prefixes = _prefixes(root)

    def is_xacro(name: str) -> bool:
        return ":" in name and name.split(":", 1)[0] in prefixes

    needed = leftover = None
    for child in root.children:
        if is_xacro(child.tag):
            what = f"<{child.tag}> at line {child.line}"
            if child.tag.split(":", 1)[1] in _DEFINITIONS:
                leftover = leftover or what
            else:
                needed = needed or what
        elif child.tag in _READ:
            for node in child.iter():
                if is_xacro(node.tag):
                    needed = needed or f"<{node.tag}> at line {node.line}"
            substitution = _substitution(child)
            if substitution is not None:
                needed = needed or substitution
        elif leftover is None:
            markup = next((f"<{n.tag}> at line {n.line}" for n in child.iter() if is_xacro(n.tag)), None)
            leftover = markup or _substitution(child)
    if leftover is None:  # <robot name="${name}">: urdfdom takes the name as it is
        leftover = next(
            (f'{k}="{v}" at line {root.line}' for k, v in root.attrib.items() if "${" in v or "$(" in v), None
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
