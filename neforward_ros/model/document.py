"""A URDF's bytes -> its XML element tree, parsed by lxml (yourdfpy's XML library) as yourdfpy parses
it, and accepted where urdfdom's TinyXML2 accepts it.

yourdfpy's ``URDF.load`` parses strictly and, when that fails, again with libxml2's recovery. Recovery
alone would also accept a truncated or mismatched document (a half-received ``robot_description``)
and silently drop what follows the break. So the document is parsed once with recovery and then
accepted only if every error libxml2 reported is one TinyXML2 does not make: a namespace prefix
with no declaration (``<gazebo:plugin>``, ``xacro:foo="..."``: TinyXML2 knows nothing of
namespaces), ``--`` inside a comment (banners of dashes), a bare ``&`` in an attribute, an XML
declaration's version other than 1.0 (pybullet's ``version="0.0"``) or after blank lines. Any other
error refuses the document, naming the first one and its line.

The root's elements keep what lxml gives: ``tag`` (``"{uri}name"`` for a declared namespace,
``"prefix:name"`` for an undeclared one), ``attrib``, ``sourceline``. Comments and processing
instructions are dropped.
"""

from __future__ import annotations

from typing import Any

from neforward_ros.errors import ModelError

TOLERATED = frozenset(
    {
        "NS_ERR_UNDEFINED_NAMESPACE",  # a prefix without xmlns: a plain name to TinyXML2
        "ERR_HYPHEN_IN_COMMENT",  # "--" inside a comment
        "ERR_ENTITYREF_SEMICOL_MISSING",  # a bare "&" followed by a name
        "ERR_NAME_REQUIRED",  # a bare "&" followed by a blank
        "ERR_UNKNOWN_VERSION",  # <?xml version="0.0"?>: TinyXML2 does not check the version
        "ERR_RESERVED_XML_NAME",  # an XML declaration after blank lines
    }
)
"""libxml2's errors (lxml ``type_name``) that TinyXML2, urdfdom's XML parser, does not make."""


def parse_document(data: bytes | str) -> Any:
    """The root element (an ``lxml.etree._Element``) of a URDF document: a file's bytes (the encoding
    from the byte-order mark or the XML declaration, UTF-8 otherwise) or XML text (a
    ``robot_description``: text, whatever encoding its declaration names).

    Raises:
        ModelError: no element, or an XML error TinyXML2 makes too, naming it and its line.
    """
    from lxml import etree  # yourdfpy's dependency; imported with it, when a model is first loaded

    encoding = None
    if isinstance(data, str):
        data, encoding = data.encode("utf-8"), "utf-8"
    parser = etree.XMLParser(recover=True, remove_comments=True, remove_pis=True, huge_tree=True, encoding=encoding)
    try:
        root = etree.fromstring(data, parser)
    except etree.XMLSyntaxError as exc:  # recovery found nothing to recover (an empty document)
        raise ModelError(f"malformed URDF XML: {exc.msg}") from None
    fatal = [error for error in parser.error_log if error.type_name not in TOLERATED]
    if fatal:
        raise ModelError(f"malformed URDF XML: {fatal[0].message.strip()} at line {fatal[0].line}")
    if root is None:
        raise ModelError("malformed URDF XML: no element")
    return root


def text_encoding(root: Any) -> str:
    """The encoding the document was read in (its declaration's, UTF-8 if it has none)."""
    return root.getroottree().docinfo.encoding or "utf-8"


def children(element: Any) -> list[Any]:
    """The element's child elements in document order (comments are already gone)."""
    return [child for child in element if isinstance(child.tag, str)]
