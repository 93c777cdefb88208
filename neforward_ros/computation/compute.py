"""The node's result from its inputs: one computation for the node (a stamp at a time) and the bag
tool (a chunk of stamps at a time).

:func:`compute` takes joint states (:class:`~neforward_ros.computation.inputs.JointStates`) and, for a
moving base, the measured link's motion at their stamps, and gives the :class:`Result` the node
publishes and the bag tool records. In order:

1. the publish policy (:mod:`.policy`) where some joints have no estimate;
2. the root's motion: at rest under ``gravity``, or from the base source's link
   (:func:`~neforward_ros.computation.base_motion.root_and_world`), with the root's world pose;
3. the forward recursion (:func:`~neforward_ros.kinematics.forward.kinematics_table`);
4. with torques, wrenches or contact asked for and every joint known: the backward pass, the
   measured efforts scaled and offset (``effort.*``), and the debounced contact state.

What runs on from one stamp to the next (the contact debounce) is in a :class:`ComputeState` the
caller holds and passes in: the node one for its model, the bag tool one per recording, fed in stamp
order, so the two give the same numbers for the same inputs.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from neforward_ros.computation.base_motion import root_and_world
from neforward_ros.computation.contact import ContactDetector
from neforward_ros.computation.inputs import JointStates, LinkMotion
from neforward_ros.computation.policy import apply_policy, hold_vector
from neforward_ros.computation.result import Dynamics, Result, make_result
from neforward_ros.kinematics.forward import kinematics_table, root_state
from neforward_ros.kinematics.inverse_dynamics import split_values, wrenches_from_table
from neforward_ros.logs import LogFunction, ThrottledLog
from neforward_ros.model import RobotModel
from neforward_ros.parameters.settings import NodeSettings


@dataclass
class ComputeState:
    """What :func:`compute` needs beyond its inputs, for one model and one stream of stamps.

    Attributes:
        hold: (n,) the positions ``publish_policy: hold`` holds joints at.
        effort_scale, effort_offset: (n,) measured = scale * effort + offset.
        contact: the contact debounce (None without ``contact.*``), which runs on from stamp to stamp.
    """

    hold: np.ndarray
    effort_scale: np.ndarray
    effort_offset: np.ndarray
    contact: ContactDetector | None

    @classmethod
    def new(cls, model: RobotModel, settings: NodeSettings, log: LogFunction | None = None) -> ComputeState:
        """The state at the start of a stream, for this model and these settings."""
        names = model.joint_names
        contact = None
        if settings.contact_thresholds:
            thresholds = np.array([settings.contact_thresholds.get(n, np.nan) for n in names])
            contact = ContactDetector(thresholds, settings.contact_debounce, names, ThrottledLog(log))
        return cls(
            hold_vector(names, settings.hold_positions),
            np.array([settings.effort_scale.get(n, 1.0) for n in names]),
            np.array([settings.effort_offset.get(n, 0.0) for n in names]),
            contact,
        )


@dataclass(frozen=True)
class Computed:
    """What :func:`compute` gives.

    Attributes:
        result: what is published for the stamps (a batch's: for the rows in ``rows`` only); None
            when nothing is (one stamp).
        rows: a batch's input rows that have a result, (T',) indices; None for one stamp.
        known: (..., n) per input row, whether each joint's state is an estimate or held (after the
            policy).
        publish: (...) per input row, whether the policy publishes it.
        base_unknown: (...) per input row, whether the base source's link was not determined there
            (a joint above it has no estimate) or is not a link of the model.
    """

    result: Result | None
    rows: np.ndarray | None
    known: np.ndarray
    publish: Any
    base_unknown: Any


def compute(
    model: RobotModel, settings: NodeSettings, states: JointStates, base: LinkMotion | None, state: ComputeState
) -> Computed:
    """The result of one stamp or of a batch of stamps (see the module docstring); ``base``: the
    measured link's motion at the same stamps for a moving base (``base.source`` imu or odometry),
    None for a fixed one."""
    single = states.single
    q, qd, qdd, known = states.q, states.qd, states.qdd, states.ready
    publish: Any = True if single else np.ones(len(states), dtype=bool)
    if not known.all():
        policy = apply_policy(settings.publish_policy, q, qd, qdd, known, states.silent, state.hold)
        q, qd, qdd, known, publish = policy.q, policy.qd, policy.qdd, policy.known, policy.publish
    determined = None if known.all() else model.determined_links(known)
    known_in = known
    base_unknown: Any = np.zeros_like(publish, dtype=bool)
    if base is not None:
        index = model.link_index.get(base.link)
        if index is None:
            base_unknown = ~base_unknown
        elif determined is not None:
            base_unknown = ~determined[..., index]
        publish = publish & ~base_unknown
    stamps, efforts = states.stamps, states.efforts
    rows = None
    if single:
        if not publish:
            return Computed(None, None, known_in, False, base_unknown)
    else:
        rows = np.flatnonzero(publish)
        if len(rows) < len(states):
            q, qd, qdd, known = q[rows], qd[rows], qdd[rows], known[rows]
            stamps, efforts = stamps[rows], efforts[rows]
            determined = None if determined is None else determined[rows]
            base = None if base is None else base.part(rows)
        if determined is not None and determined.all():
            determined = None
    world = None
    if base is None:
        root = root_state(settings.gravity)
    else:
        root, world = root_and_world(model, q, qd, qdd, base, settings.world_states)
    table = kinematics_table(model, q, qd, qdd, root)
    result = make_result(model, stamps, table, determined)
    if world is not None and (not single or np.isfinite(world[0]).all()):
        result = replace(result, world=world)
    if settings.dynamics_needed and (not single or determined is None):
        force, moment, torques = split_values(model, wrenches_from_table(model, q, table))
        complete = known.all(axis=-1)
        if not single:
            torques = np.where(complete[:, None], torques, np.nan)  # no dynamics where a joint has no state
        measured = state.effort_scale * efforts + state.effort_offset
        dynamics = Dynamics(model.joint_names, q, qd, torques, measured, force, moment)
        contact = None
        if state.contact is not None:
            if single:
                contact = state.contact.update(stamps, dynamics.external)
            else:
                contact = state.contact.update_many(stamps, dynamics.external, complete)
        result = replace(result, dynamics=dynamics, contact=contact)
    return Computed(result, rows, known_in, publish, base_unknown)
