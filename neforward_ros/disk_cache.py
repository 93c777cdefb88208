"""What is derived once and kept on disk: the facts of ROS 2 message types.

Knowing a message type (its fields, definition and type hash) means building rosbags' whole ROS 2
Jazzy type store (200 classes, 0.1 s). The facts depend only on the type and the rosbags release,
so they are kept as JSON files whose names are a SHA-256 of those inputs and of this cache's format:
a ``neforward bag`` run, a node start or ``neforward echo`` with types seen before needs no type
store. A file that does not read back is ignored and rewritten; a cache that cannot be written is
simply not used.

The directory is ``$NEFORWARD_CACHE``, else ``$XDG_CACHE_HOME/neforward_ros``, else
``~/.cache/neforward_ros``. ``NEFORWARD_CACHE=off`` turns the cache off.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from pathlib import Path
from typing import Any

FORMAT = 4
"""Bumped whenever what is kept changes, so that older files are not read."""


def directory() -> Path | None:
    """Where things are kept, or None when the cache is off."""
    chosen = os.environ.get("NEFORWARD_CACHE", "")
    if chosen.lower() in ("0", "off", "false", "no"):
        return None
    if chosen:
        return Path(chosen)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "neforward_ros"


def _path(kind: str, *inputs: bytes | str) -> Path | None:
    folder = directory()
    if folder is None:
        return None
    digest = hashlib.sha256(f"neforward {kind} {FORMAT}".encode())
    for part in inputs:
        data = part.encode() if isinstance(part, str) else part
        digest.update(len(data).to_bytes(8, "little"))
        digest.update(data)
    return folder / kind / f"{digest.hexdigest()}.json"


def load(kind: str, *inputs: bytes | str) -> Any:
    """What was kept for these inputs, or None."""
    path = _path(kind, *inputs)
    if path is None:
        return None
    try:
        contents = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return contents.get("value") if isinstance(contents, dict) and contents.get("format") == FORMAT else None


def store(kind: str, *inputs: bytes | str, value: Any) -> None:
    """Keep a JSON-able value for these inputs (best effort)."""
    path = _path(kind, *inputs)
    if path is None:
        return
    partial = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile("w", dir=path.parent, suffix=".partial", delete=False) as stream:
            partial = stream.name
            json.dump({"format": FORMAT, "value": value}, stream)
        os.replace(partial, path)
    except OSError:
        if partial is not None:
            Path(partial).unlink(missing_ok=True)
