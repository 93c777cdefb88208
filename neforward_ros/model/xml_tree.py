"""XML -> a light element tree, read as leniently as ROS's own URDF parser reads it.

urdfdom (robot_state_publisher's and Pinocchio's parser) reads XML with TinyXML2, which knows
nothing of namespaces: ``<gazebo:plugin>`` or ``xacro:foo="..."`` with no ``xmlns`` declaration
are plain names to it, where a namespace-aware parser stops at an "unbound prefix". TinyXML2 also
accepts ``--`` inside comments and a bare ``&`` in an attribute, which XML forbids and published
descriptions contain (comment banners of dashes are common). So the text is read here with expat
with namespace processing off, after comments are blanked (their lines kept, so that error line
numbers stay right) and bare ampersands escaped. Element and attribute names keep their prefixes
(``xacro:property``, ``xmlns:xacro``).
"""

from __future__ import annotations

import codecs
import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from xml.parsers import expat

from neforward_ros.errors import ModelError


@dataclass(slots=True)
class Element:
    """One element: its name (with any prefix), attributes, children in order, text, and line."""

    tag: str
    attrib: dict[str, str]
    line: int
    children: list[Element] = field(default_factory=list)
    text: str = ""

    def find(self, tag: str) -> Element | None:
        """The first child named ``tag`` (as TinyXML2's FirstChildElement), or None."""
        for child in self.children:
            if child.tag == tag:
                return child
        return None

    def findall(self, tag: str) -> list[Element]:
        """Every child named ``tag``, in order."""
        return [child for child in self.children if child.tag == tag]

    def iter(self) -> Iterator[Element]:
        """This element and every element below it, depth first, in document order."""
        stack = [self]
        while stack:
            element = stack.pop()
            yield element
            stack.extend(reversed(element.children))


_COMMENT = re.compile(r"<!--.*?-->", re.DOTALL)
_DECLARATION = re.compile(r"^\s*<\?xml[^>]*\?>")
_ENCODING = re.compile(rb"^\s*<\?xml[^>]*encoding\s*=\s*[\"']([A-Za-z0-9._-]+)[\"']")
_BARE_AMPERSAND = re.compile(r"&(?!(?:[A-Za-z_][\w.-]*|#[0-9]+|#x[0-9A-Fa-f]+);)")


def decode(data: bytes) -> str:
    """A file's bytes as text: by its byte-order mark, else its XML declaration's encoding, else
    UTF-8; bytes that are not in that encoding are read as Latin-1 (never an error, as TinyXML2)."""
    for mark, encoding in (
        (codecs.BOM_UTF8, "utf-8"),
        (codecs.BOM_UTF16_LE, "utf-16"),
        (codecs.BOM_UTF16_BE, "utf-16"),
    ):
        if data.startswith(mark):
            return data.decode(encoding)
    declared = _ENCODING.match(data)
    encoding = declared.group(1).decode("ascii") if declared else "utf-8"
    try:
        return data.decode(encoding)
    except (LookupError, UnicodeDecodeError):
        return data.decode("latin-1")


def _blank_comment(match: re.Match[str]) -> str:
    return "\n" * match.group(0).count("\n")


def parse_xml(text: str) -> Element:
    """The document's root element.

    Raises:
        ModelError: text that is not XML even by TinyXML2's standard (an unclosed or mismatched
            element, a broken attribute), naming the line.
    """
    text = _DECLARATION.sub(lambda m: "\n" * m.group(0).count("\n"), text, count=1)
    text = _BARE_AMPERSAND.sub("&amp;", _COMMENT.sub(_blank_comment, text))
    parser = expat.ParserCreate(encoding="utf-8")  # no namespace_separator: prefixes stay in names
    parser.buffer_text = True
    stack: list[Element] = []
    root: list[Element] = []

    def start(name: str, attributes: dict[str, str]) -> None:
        element = Element(name, attributes, parser.CurrentLineNumber)
        if stack:
            stack[-1].children.append(element)
        else:
            root.append(element)
        stack.append(element)

    def end(name: str) -> None:
        stack.pop()

    def characters(data: str) -> None:
        if stack:
            stack[-1].text += data

    parser.StartElementHandler = start
    parser.EndElementHandler = end
    parser.CharacterDataHandler = characters
    try:
        parser.Parse(text, True)
    except expat.ExpatError as exc:
        raise ModelError(f"malformed URDF XML: {expat.ErrorString(exc.code)} at line {exc.lineno}") from exc
    if not root:
        raise ModelError("malformed URDF XML: no element")
    return root[0]
