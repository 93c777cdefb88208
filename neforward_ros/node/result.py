"""What the node publishes for one stamp (or, batched, for many): link kinematics as messages need them."""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property
from typing import Any

import numpy as np

from neforward_ros.model import RobotModel
from neforward_ros.recursion import LinkKinematics


@dataclass(frozen=True)
class Result:
    """Everything published for one stamp, or (arrays with a leading sample axis) for many.

    Attributes:
        stamp_ns: the stamp of the joint state it comes from, integer nanoseconds; (T,) for a batch.
        link_names, root_link: the model's.
        table: the recursion's rows, (n_links, ROW) or (T, n_links, ROW)
            (see :func:`neforward_ros.recursion.kinematics_table`).
    """

    stamp_ns: Any
    link_names: tuple[str, ...]
    root_link: str
    table: np.ndarray

    @cached_property
    def in_link(self) -> LinkKinematics:
        """Vectors in each link's own frame; poses, centres of mass and orientations in the root frame."""
        return LinkKinematics.from_table(self.link_names, self.table)

    @cached_property
    def in_root(self) -> LinkKinematics:
        """The same vectors along the root frame's axes."""
        return self.in_link.in_root()

    def sample(self, index: int) -> Result:
        """One sample of a batched result."""
        return replace(self, stamp_ns=int(self.stamp_ns[index]), table=self.table[index])


def make_result(model: RobotModel, stamp_ns: Any, table: np.ndarray) -> Result:
    """A Result from the recursion's rows, for one sample or a batch."""
    return Result(stamp_ns=stamp_ns, link_names=model.link_names, root_link=model.root_link, table=table)
