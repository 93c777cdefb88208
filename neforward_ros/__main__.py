"""``python -m neforward_ros``: the ``neforward`` command."""

from neforward_ros.command import entry

entry()
