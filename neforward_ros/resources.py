"""Files shipped with the package: the bundled robot and the default parameters (``config/``)."""

from __future__ import annotations

import sys
from pathlib import Path

PACKAGE = "neforward_ros"
DEFAULT_ROBOT = "panda.urdf"
"""The bundled arm, in config/."""


def bundled_config_path(name: str) -> Path:
    """Path of a file shipped in the package's ``config/`` folder.

    Looked up in the ROS package share folder when ament_index_python is importable, then beside the
    source tree (a checkout or an editable install), then in ``<prefix>/share/neforward_ros/config``
    where pip puts the package's data files.
    """
    candidates = []
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_share_directory

        try:
            candidates.append(Path(get_package_share_directory(PACKAGE)) / "config" / name)
        except PackageNotFoundError:
            pass
    except ImportError:
        pass
    candidates.append(Path(__file__).resolve().parent.parent / "config" / name)
    candidates.append(Path(sys.prefix) / "share" / PACKAGE / "config" / name)
    for path in candidates:
        if path.is_file():
            return path
    raise FileNotFoundError(f"{name} is not in any of: {', '.join(str(p.parent) for p in candidates)}")
