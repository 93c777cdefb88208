"""What the node publishes for one stamp (or, batched, for many): link kinematics as messages need them."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from neforward_ros.model import RobotModel
from neforward_ros.recursion import LinkKinematics
from neforward_ros.rotations import quaternions


@dataclass(frozen=True)
class Result:
    """Everything published for one stamp.

    Attributes:
        stamp_ns: the stamp of the joint state it comes from, integer nanoseconds.
        link_names, root_link: the model's.
        in_link: one sample of the recursion, vectors in each link's own frame.
        in_root: the same vectors along the root frame's axes.
        com_position_in_root: each link's centre of mass in the root frame, m, (n_links, 3).
        com_velocity_in_root: velocity of each centre of mass along the root axes, m/s.
        orientation_in_root: each link frame's orientation in the root frame, unit quaternions
            (x, y, z, w), (n_links, 4).
        joints: the joint state it was computed from.
    """

    stamp_ns: int
    link_names: tuple[str, ...]
    root_link: str
    in_link: LinkKinematics
    in_root: LinkKinematics
    com_position_in_root: np.ndarray
    com_velocity_in_root: np.ndarray
    orientation_in_root: np.ndarray
    joints: Any

    def sample(self, index: int) -> Result:
        """One sample of a batched result (arrays with a leading sample axis)."""

        def pick(kin: LinkKinematics) -> LinkKinematics:
            fields = ("omega", "alpha", "velocity", "accel", "com_accel", "position", "rotation")
            return replace(kin, **{name: getattr(kin, name)[index] for name in fields})

        return replace(
            self,
            stamp_ns=int(self.stamp_ns[index]),
            in_link=pick(self.in_link),
            in_root=pick(self.in_root),
            com_position_in_root=self.com_position_in_root[index],
            com_velocity_in_root=self.com_velocity_in_root[index],
            orientation_in_root=self.orientation_in_root[index],
            joints=None,
        )


def make_result(model: RobotModel, stamp_ns: Any, in_link: LinkKinematics, joints: Any) -> Result:
    """A Result from the recursion's output, for one sample or (with a leading sample axis) many.

    Args:
        model: the robot.
        stamp_ns: int, or (T,) integer nanoseconds for a batch.
        in_link: forward_recursion's output (vectors in link frames).
        joints: the joint states it came from (a JointEstimate, or the batch's arrays).
    """
    in_root = in_link.in_root()
    c = np.asarray(model.com_in_link, dtype=float)
    com_velocity_in_link = in_link.velocity + np.cross(in_link.omega, c)
    rotation = in_link.rotation
    return Result(
        stamp_ns=stamp_ns,
        link_names=model.link_names,
        root_link=model.root_link,
        in_link=in_link,
        in_root=in_root,
        com_position_in_root=in_link.position + (rotation @ c[:, :, None])[..., 0],
        com_velocity_in_root=np.einsum("...kij,...kj->...ki", rotation, com_velocity_in_link),
        orientation_in_root=quaternions(rotation),
        joints=joints,
    )
