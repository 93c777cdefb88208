"""``load_model``: a URDF file or text -> a :class:`RobotModel`.

The XML is parsed by lxml and read by yourdfpy (:mod:`.document`, :mod:`.urdf`); yourdfpy is imported
the first time a model is loaded (:mod:`.reader`), which takes about a second (it imports trimesh), so
a model built from a description that needs no xacro is kept in the disk cache (:mod:`.stored`) and a
description seen before is not read again."""

from __future__ import annotations

import logging
import os
from dataclasses import replace

from neforward_ros.errors import ModelError
from neforward_ros.logs import LogFunction, python_log
from neforward_ros.model import xacro
from neforward_ros.model.build import build_model
from neforward_ros.model.document import parse_document, text_encoding
from neforward_ros.model.stored import store_model, stored_model
from neforward_ros.model.types import RobotModel
from neforward_ros.model.urdf import read_robot


def load_model(
    source: str | os.PathLike[str], *, root_link: str | None = None, log: LogFunction | None = None
) -> RobotModel:
    """Build a :class:`RobotModel` from a URDF, as ROS's parser (urdfdom) reads it.

    Args:
        source: a URDF file path, or the URDF XML text itself (what a ``robot_description``
            parameter or topic holds). A string whose first non-blank character is ``<`` is
            taken as XML. A ``.xacro`` file, or a file that uses xacro where the robot is described
            (see :mod:`neforward_ros.model.xacro`), is expanded with the ``xacro`` package first; a
            file that only declares the xacro namespace is a plain URDF. A ``<robot>`` without a
            name is named ``robot``.
        root_link: the link whose frame is the root frame; the recursion covers the subtree
            below it and treats it as fixed in the inertial frame. Default: the URDF's root link.
        log: where the model's :attr:`~RobotModel.warnings` are said, once per call; the Python
            logger ``neforward_ros`` by default.

    Raises:
        ModelError: the file is missing, the text is not XML, the URDF is not a single tree, a
            joint lacks a type, parent or child or has a zero axis, a number is not a finite number,
            an ``<inertial>`` lacks its mass or inertia, ``root_link`` is not a link of the URDF, a
            xacro file cannot be expanded (or the ``xacro`` package is missing: the message says how
            to expand it), or XML text uses xacro. The message names the element and its line.
    """
    data, path = _read_source(source)
    model = _parse(data, path, root_link)
    say = log if log is not None else python_log()
    for warning in model.warnings:
        say(logging.WARNING, warning)
    return model


def description_text(path: str | os.PathLike[str]) -> str:
    """The URDF XML of a file, expanded by xacro when it needs it: what a ``robot_description`` holds.

    Raises:
        ModelError: as :func:`load_model`.
    """
    data, file = _read_source(os.fspath(path))
    root = parse_document(data)
    if file is not None and (file.endswith(".xacro") or xacro.xacro_use(root).needed is not None):
        return xacro.expand(file).decode("utf-8")
    return data if isinstance(data, str) else data.decode(text_encoding(root), errors="replace")


def _read_source(source: str | os.PathLike[str]) -> tuple[bytes | str, str | None]:
    """(the file's bytes or the XML text, the file's path or None for XML text)."""
    if isinstance(source, str) and source.lstrip().startswith("<"):
        return source, None
    if not isinstance(source, (str, os.PathLike)):
        raise ModelError(f"URDF source must be a path or an XML string, not {type(source).__name__}")
    path = os.fspath(source)
    if not path.strip():
        raise ModelError("URDF source is empty: give a file path or the URDF XML text")
    try:
        with open(path, "rb") as stream:
            data = stream.read()
    except OSError as exc:
        raise ModelError(f"cannot read URDF file {path!r}: {exc.strerror or exc}") from exc
    return data, path


def _parse(data: bytes | str, path: str | None, root_link: str | None) -> RobotModel:
    root = parse_document(data)
    use = xacro.xacro_use(root)
    expanded = path is not None and (path.endswith(".xacro") or use.needed is not None)
    if expanded:
        root = parse_document(xacro.expand(path))
        use = xacro.xacro_use(root)
    if use.needed is not None:
        raise ModelError(
            f"the URDF text is an unexpanded xacro file (it uses {use.needed}): expand it first "
            "(xacro robot.urdf.xacro > robot.urdf), as the launch file does"
        )
    kept = None if expanded else stored_model(data, root_link)
    if kept is not None:
        return kept
    model = build_model(read_robot(root), root_link)
    if use.leftover is not None:
        ignored = (
            f"robot {model.name!r}: xacro markup where urdfdom does not read ({use.leftover}) is ignored, as urdfdom "
            "ignores it; the links and joints use none"
        )
        model = replace(model, warnings=(*model.warnings, ignored))
    if not expanded:
        store_model(data, root_link, model)
    return model
