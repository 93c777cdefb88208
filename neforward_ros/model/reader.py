"""yourdfpy, the URDF library, imported when a model is first loaded and kept quiet.

Importing yourdfpy imports trimesh (about 0.6-1 s), so nothing imports it before a URDF is read.
Its loggers (and trimesh's, which reports optional modules it misses at import) are held at ERROR
while it is imported; its element readers log nothing. A URDF's own doubtful points are said by the
model's warnings.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

_LOGGERS = ("yourdfpy", "trimesh")


@contextmanager
def quiet() -> Iterator[None]:
    """yourdfpy's and trimesh's loggers at ERROR or above inside the block."""
    loggers = [logging.getLogger(name) for name in _LOGGERS]
    levels = [logger.level for logger in loggers]
    for logger in loggers:
        logger.setLevel(max(logger.getEffectiveLevel(), logging.ERROR))
    try:
        yield
    finally:
        for logger, level in zip(loggers, levels, strict=True):
            logger.setLevel(level)


def yourdfpy_urdf() -> Any:
    """``yourdfpy.URDF``, whose element readers (``_parse_joint``, ``_parse_inertial`` ...) read a
    URDF's joints and inertials.

    Raises:
        ModelError: yourdfpy is not installed (it is a dependency of the package: pip install yourdfpy).
    """
    with quiet():
        try:
            from yourdfpy import URDF
        except ImportError as exc:
            from neforward_ros.errors import ModelError

            raise ModelError(f"reading a URDF needs yourdfpy: pip install yourdfpy ({exc})") from exc
    return URDF
