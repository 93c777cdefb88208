"""What the node publishes for one stamp (or, batched, for many): link kinematics as messages need them."""

from __future__ import annotations

import itertools
from collections.abc import Mapping
from dataclasses import dataclass, replace
from functools import cached_property
from typing import Any

import numpy as np

from neforward_ros.kinematics.forward import LinkKinematics
from neforward_ros.kinematics.forward_kernel import SLICES
from neforward_ros.model import RobotModel


@dataclass(frozen=True)
class Dynamics:
    """The backward pass of one stamp, or (a leading sample axis) of many: what ~/joint_torques,
    ~/external_torques and ~/<link>/wrench publish.

    Attributes:
        joint_names: the model's joint columns.
        positions, velocities: (..., n) the joint states it was computed from (as estimated).
        torques: (..., n) the model's joint torques, N m (N for prismatic joints).
        external: (..., n) measured - model, the model being ``torques`` plus friction
            (``friction.*``): the torque the motors give beyond what the motion needs (see the
            README for its sign); NaN where the input had no effort, and everywhere when the
            momentum observer gives the external torques instead (:class:`Observation`).
        force, moment: (..., n_links, 3) what each link receives through its parent joint, N and N m
            about the link origin, link frame (see :class:`neforward_ros.InverseDynamics`).
    """

    joint_names: tuple[str, ...]
    positions: np.ndarray
    velocities: np.ndarray
    torques: np.ndarray
    external: np.ndarray
    force: np.ndarray
    moment: np.ndarray

    def part(self, index: Any) -> Dynamics:
        """The samples ``index`` (an int, a slice or an index array) of a batch."""
        return Dynamics(self.joint_names, *(getattr(self, name)[index] for name in _DYNAMICS_FIELDS))


_DYNAMICS_FIELDS = ("positions", "velocities", "torques", "external", "force", "moment")


@dataclass(frozen=True)
class JointMotion:
    """The joint states a result was computed from, one stamp or (a leading sample axis) many: what
    ~/joint_estimates publishes.

    Attributes:
        joint_names: the model's joint columns.
        positions, velocities, accelerations: (..., n) rad, rad/s, rad/s^2 (m, m/s, m/s^2 for a
            prismatic joint), as estimated (or supplied, or held by the publish policy).
        acceleration_std: (..., n) the estimator's standard deviation of each acceleration, same
            units; NaN where it states none (a fixed window, supplied states).
        known: (..., n) whether each joint's state is an estimate (or supplied, or held).
    """

    joint_names: tuple[str, ...]
    positions: np.ndarray
    velocities: np.ndarray
    accelerations: np.ndarray
    acceleration_std: np.ndarray
    known: np.ndarray

    def part(self, index: Any) -> JointMotion:
        """The samples ``index`` (an int, a slice or an index array) of a batch."""
        return JointMotion(self.joint_names, *(getattr(self, name)[index] for name in _MOTION_FIELDS))


_MOTION_FIELDS = ("positions", "velocities", "accelerations", "acceleration_std", "known")


@dataclass(frozen=True)
class Observation:
    """The momentum observer's output (:mod:`neforward_ros.computation.observer`) at one raw sample's
    stamp, or (a leading sample axis) at many: what ~/external_torques, ~/contact and
    ~/contact_wrench publish when the observer gives the external torques.

    Attributes:
        stamp_ns: int ns, or (T,) int64.
        joint_names: the model's joint columns.
        positions, velocities: (..., n) the measured joint states.
        external: (..., n) N m (N), NaN where unknown (the observer's first sample, a joint without an
            effort).
        contact: ~/contact's state (a batch's: (T,) floats, 1 or 0, NaN where unknown); None without
            ``contact.*``.
        wrench: (..., 6) ~/contact_wrench's force and moment at ``link``'s origin, in its frame; None
            without ``contact.link``.
        link: the link of ``wrench``.
        still: whether every joint is slower than its friction's velocity scale (its filtered
            velocity; (T,) for many samples): where the contact's rest test may apply.
    """

    stamp_ns: Any
    joint_names: tuple[str, ...]
    positions: np.ndarray
    velocities: np.ndarray
    external: np.ndarray
    contact: Any = None
    wrench: np.ndarray | None = None
    link: str = ""
    still: Any = None

    def sample(self, index: int) -> Observation:
        """One sample of a batch."""
        contact = self.contact
        if contact is not None:
            contact = None if not np.isfinite(contact[index]) else bool(contact[index])
        return replace(
            self,
            stamp_ns=int(self.stamp_ns[index]),
            positions=self.positions[index],
            velocities=self.velocities[index],
            external=self.external[index],
            contact=contact,
            wrench=None if self.wrench is None else self.wrench[index],
            still=None if self.still is None else bool(self.still[index]),
        )

    def part(self, index: Any) -> Observation:
        """Samples ``index`` (a slice or an index array) of a batch."""
        return replace(
            self,
            stamp_ns=self.stamp_ns[index],
            positions=self.positions[index],
            velocities=self.velocities[index],
            external=self.external[index],
            contact=None if self.contact is None else self.contact[index],
            wrench=None if self.wrench is None else self.wrench[index],
            still=None if self.still is None else self.still[index],
        )


@dataclass(frozen=True)
class Result:
    """Everything published for one stamp, or (arrays with a leading sample axis) for many.

    Attributes:
        stamp_ns: the stamp of the joint state it comes from, integer nanoseconds; (T,) for a batch.
        link_names, root_link: the links published, in the model's order, and the model's root.
        table: the recursion's rows of those links, (n_links, ROW) or (T, n_links, ROW)
            (see :func:`neforward_ros.kinematics.forward.kinematics_table`).
        link_ids: each row's link index in the model (marker ids); None when the rows are every link.
        determined: a batch's (T, n_links) per sample, whether the link's numbers are estimates (every
            joint that moves it had one); None when all are. :meth:`runs` splits a batch by it.
        dynamics: joint torques and wrenches, when asked for and every joint has a state (a batch's:
            NaN at the samples where some joint has none).
        contact: ~/contact's state at this stamp, when contact thresholds are set and measured (a
            batch's: (T,) floats, 1 or 0, NaN where unknown).
        world: the root's pose in the world, (rotation root -> world (..., 3, 3), position (..., 3)),
            when the base source gives orientation (a zero position when it gives none).
        imu_covariance: per ``imu_links`` link, the covariance of its linear acceleration (..., 3, 3),
            link frame, m^2/s^4, from the joints' acceleration uncertainty; NaN where unknown.
        joints: the joint states the result was computed from, with ``publish_joint_estimates``.
    """

    stamp_ns: Any
    link_names: tuple[str, ...]
    root_link: str
    table: np.ndarray
    link_ids: tuple[int, ...] | None = None
    determined: np.ndarray | None = None
    dynamics: Dynamics | None = None
    contact: Any = None
    world: tuple[np.ndarray, np.ndarray] | None = None
    imu_covariance: Mapping[str, np.ndarray] | None = None
    joints: JointMotion | None = None

    @property
    def ids(self) -> tuple[int, ...]:
        """Each row's link index in the model."""
        return self.link_ids if self.link_ids is not None else tuple(range(len(self.link_names)))

    def only(self, links: np.ndarray) -> Result:
        """The same result for the links where ``links`` (n_links,) is True."""
        keep = np.flatnonzero(links)
        if len(keep) == len(self.link_names):
            return replace(self, determined=None)
        ids = self.ids
        return replace(
            self,
            link_names=tuple(self.link_names[k] for k in keep),
            table=self.table[..., keep, :],
            link_ids=tuple(ids[k] for k in keep),
            determined=None,
        )

    def runs(self) -> list[tuple[slice, Result]]:
        """A batch as runs of consecutive samples with the same determined links: (samples, the run's
        result for those links only)."""
        count = len(self.stamp_ns)
        if self.determined is None or self.determined.all():
            return [(slice(0, count), replace(self, determined=None))]
        changes = np.flatnonzero(np.any(self.determined[1:] != self.determined[:-1], axis=1)) + 1
        edges = [0, *changes.tolist(), count]
        out = []
        for start, stop in itertools.pairwise(edges):
            part = slice(start, stop)
            run = replace(
                self,
                stamp_ns=self.stamp_ns[part],
                table=self.table[part],
                determined=None,
                dynamics=None if self.dynamics is None else self.dynamics.part(part),
                contact=None if self.contact is None else self.contact[part],
                world=None if self.world is None else (self.world[0][part], self.world[1][part]),
                imu_covariance=None
                if self.imu_covariance is None
                else {k: v[part] for k, v in self.imu_covariance.items()},
                joints=None if self.joints is None else self.joints.part(part),
            )
            out.append((part, run.only(self.determined[start])))
        return out

    @cached_property
    def blocks(self) -> tuple[Blocks, Blocks]:
        """The numbers of link_states and of com_states (see :func:`state_blocks`), computed once."""
        return state_blocks(self.table)

    @cached_property
    def in_link(self) -> LinkKinematics:
        """Vectors in each link's own frame; poses, centres of mass and orientations in the root frame."""
        return LinkKinematics.from_table(self.link_names, self.table)

    @cached_property
    def in_root(self) -> LinkKinematics:
        """The same vectors along the root frame's axes (the rows give them)."""
        return LinkKinematics.from_table(self.link_names, self.table, frame="root")

    def sample(self, index: int) -> Result:
        """One sample of a batched result (all of whose links are determined). Its message numbers
        are the batch's own, so the messages of a sample are byte for byte those of the batch."""
        dynamics = None
        if self.dynamics is not None and np.isfinite(self.dynamics.torques[index]).all():
            dynamics = self.dynamics.part(index)
        contact = None
        if self.contact is not None and np.isfinite(self.contact[index]):
            contact = bool(self.contact[index])
        world = None
        if self.world is not None and np.isfinite(self.world[0][index]).all():
            world = (self.world[0][index], self.world[1][index])
        sample = replace(
            self,
            stamp_ns=int(self.stamp_ns[index]),
            table=self.table[index],
            determined=None,
            dynamics=dynamics,
            contact=contact,
            world=world,
            imu_covariance=None
            if self.imu_covariance is None
            else {k: v[index] for k, v in self.imu_covariance.items()},
            joints=None if self.joints is None else self.joints.part(index),
        )
        if "blocks" in self.__dict__:
            sample.__dict__["blocks"] = tuple(tuple(b[index] for b in blocks) for blocks in self.blocks)
        return sample


def make_result(model: RobotModel, stamp_ns: Any, table: np.ndarray, determined: np.ndarray | None = None) -> Result:
    """A Result from the recursion's rows of every link, for one sample or a batch; ``determined``
    (n_links,) for one sample keeps only those links, (T, n_links) for a batch marks them."""
    result = Result(stamp_ns=stamp_ns, link_names=model.link_names, root_link=model.root_link, table=table)
    if determined is None or determined.all():
        return result
    if determined.ndim == 1:
        return result.only(determined)
    return replace(result, determined=determined)


def _between(first: str, last: str) -> slice:
    """The columns of the recursion's rows (kernel.SLICES) from field ``first`` to field ``last``."""
    return slice(SLICES[first].start, SLICES[last].stop)


# The blocks of the two MultiDOF messages: each a slice of the kernel's row.
_LINK_POSE = _between("position", "orientation")
_COM_POSE = _between("com_position", "com_orientation")
_LINK_VELOCITIES = _between("velocity_in_root", "omega_in_root")
_LINK_ACCELERATIONS = _between("accel_in_root", "alpha_in_root")
_COM_VELOCITIES = _between("com_velocity_in_root", "com_omega_in_root")
_COM_ACCELERATIONS = _between("com_accel_in_root", "com_alpha_in_root")

Blocks = tuple[np.ndarray, np.ndarray, np.ndarray]


def state_blocks(table: np.ndarray) -> tuple[Blocks, Blocks]:
    """The numbers of link_states and of com_states from the recursion's rows ((n, ROW) or
    (T, n, ROW)): for each, transforms (..., n, 7) = translation, rotation (x, y, z, w; w >= 0, as the
    kernel gives it); velocities (..., n, 6) = linear, angular; accelerations likewise, every vector
    along the root axes (as the kernel gives them: ``*_in_root``); views of the rows."""
    return (
        (table[..., _LINK_POSE], table[..., _LINK_VELOCITIES], table[..., _LINK_ACCELERATIONS]),
        (table[..., _COM_POSE], table[..., _COM_VELOCITIES], table[..., _COM_ACCELERATIONS]),
    )
