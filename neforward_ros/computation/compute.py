"""The node's results from its inputs: one computation for the node (a stamp at a time) and the bag
tool (a chunk of stamps at a time).

:func:`compute` takes joint states (:class:`~neforward_ros.computation.inputs.JointStates`) and, for a
moving base, the measured link's motion at their stamps, and gives the :class:`Result` the node
publishes and the bag tool records. In order:

1. the publish policy (:mod:`.policy`) where some joints have no estimate;
2. the root's motion: at rest under ``gravity``, or from the base source's link
   (:func:`~neforward_ros.computation.base_motion.root_and_world`), with the root's world pose;
3. the forward recursion (:func:`~neforward_ros.kinematics.forward.kinematics_table`);
4. with torques, wrenches or contact asked for and every joint known: the backward pass and, where
   the external torques are taken as measured - model (``external_torques.method: difference``),
   those and the debounced contact state.

:func:`observe_raw` takes the measured joint states at the newest stamps
(:class:`~neforward_ros.computation.observer.RawStates`) and, where the momentum observer gives the
external torques, gives them, the contact state and the contact wrench at once, with no estimator
lag (an :class:`~neforward_ros.computation.result.Observation`).

What runs on from one stamp to the next (the observer, the contact debounce) is in a
:class:`ComputeState` the caller holds and passes in: the node one for its model, the bag tool one
per recording, fed in stamp order, so the two give the same numbers for the same inputs.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from neforward_ros.computation.base_motion import root_and_world
from neforward_ros.computation.contact import ContactDetector
from neforward_ros.computation.inputs import JointStates, LinkMotion
from neforward_ros.computation.observer import ObserverState, RawStates, observe
from neforward_ros.computation.policy import apply_policy, hold_vector
from neforward_ros.computation.result import Dynamics, JointMotion, Observation, Result, make_result
from neforward_ros.kinematics.effort_model import EffortModel
from neforward_ros.kinematics.forward import kinematics_table, root_state
from neforward_ros.kinematics.forward_kernel import SLICES
from neforward_ros.kinematics.inverse_dynamics import split_values, wrenches_from_table
from neforward_ros.kinematics.jacobian import jacobian_from_table, wrench_at_link
from neforward_ros.logs import LogFunction, ThrottledLog
from neforward_ros.model import RobotModel
from neforward_ros.parameters.settings import NodeSettings


@dataclass
class ComputeState:
    """What :func:`compute` and :func:`observe_raw` need beyond their inputs, for one model and one
    stream of stamps.

    Attributes:
        hold: (n,) the positions ``publish_policy: hold`` holds joints at.
        effort: the joints' effort and friction model (``effort.*``, ``friction.*``).
        contact: the contact debounce (None without ``contact.*``), which runs on from stamp to stamp:
            fed by whichever method gives the external torques.
        observer: the momentum observer's state; None where it cannot run (a moving base) or is not
            wanted (``external_torques.method: difference``, or nothing that needs external torques).
        method: how the external torques are estimated: "observer" or "difference"; None while
            ``auto`` has not seen every joint yet (see :meth:`decide`).
    """

    hold: np.ndarray
    effort: EffortModel
    contact: ContactDetector | None
    observer: ObserverState | None
    method: str | None
    log: ThrottledLog

    @classmethod
    def new(cls, model: RobotModel, settings: NodeSettings, log: LogFunction | None = None) -> ComputeState:
        """The state at the start of a stream, for this model and these settings."""
        names = model.joint_names
        throttled = ThrottledLog(log)
        contact = None
        if settings.contact_thresholds:
            thresholds = np.array([settings.contact_thresholds.get(n, np.nan) for n in names])
            rest = None
            if settings.contact_rest_thresholds:
                rest = np.array([settings.contact_rest_thresholds.get(n, np.nan) for n in names])
            accelerations = None
            if settings.contact_accelerations:
                accelerations = np.array([settings.contact_accelerations.get(n, np.nan) for n in names])
            contact = ContactDetector(
                thresholds, settings.contact_debounce, names, throttled, settings.contact_release, rest, accelerations
            )
        friction = settings.friction
        effort = EffortModel.of(
            names,
            settings.effort_scale,
            settings.effort_offset,
            friction.get("coulomb"),
            friction.get("viscous"),
            friction.get("velocity_scale"),
            friction.get("stribeck"),
            friction.get("stribeck_velocity"),
            settings.effort_armature,
        )
        observer, method = None, "difference"
        if observer_wanted(settings):
            gains = np.array([settings.observer_gains.get(n, settings.observer_gain) for n in names])
            zones = np.array([settings.dead_zones.get(n, 0.0) for n in names])
            observer = ObserverState(gains, settings.gravity, settings.velocity_cutoff, settings.slow_gain, zones)
            method = "observer" if settings.external_method == "observer" else None
        return cls(hold_vector(names, settings.hold_positions), effort, contact, observer, method, throttled)

    def decide(self, velocities: bool) -> None:
        """``auto``, once every joint has a sample: the observer when the joint states carry
        velocities, else the difference."""
        if self.method is not None:
            return
        self.method = "observer" if velocities else "difference"
        self.log.log(
            logging.INFO,
            "external torques: momentum observer at the newest sample (the joint states carry velocities)"
            if velocities
            else "external torques: measured - model at the estimator's stamps (the joint states carry no velocities, "
            "which the momentum observer needs)",
        )


def observer_wanted(settings: NodeSettings) -> bool:
    """Whether the momentum observer may give the external torques with these settings: something
    needs them (torques, contact), the base is fixed, and the method is not ``difference``."""
    needed = settings.publish_torques or bool(settings.contact_thresholds) or bool(settings.contact_link)
    return needed and settings.external_method != "difference" and settings.base_source == "fixed"


@dataclass(frozen=True)
class Computed:
    """What :func:`compute` gives.

    Attributes:
        result: what is published for the stamps (a batch's: for the rows in ``rows`` only); None
            when nothing is (one stamp, or a batch none of whose rows is published).
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
        if not len(rows):  # a block with nothing to publish (stamps the estimates do not cover, at an end)
            return Computed(None, rows, known_in, publish, base_unknown)
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
    spread = states.acceleration_std
    if spread is not None and not single and rows is not None:
        spread = spread[rows]
    if settings.imu_links and spread is not None:
        result = replace(result, imu_covariance=imu_covariances(model, table, spread, settings.imu_links))
    if settings.publish_joint_estimates:
        stated = spread if spread is not None else np.full_like(q, np.nan)
        result = replace(result, joints=JointMotion(model.joint_names, q, qd, qdd, stated, known))
    if world is not None and (not single or np.isfinite(world[0]).all()):
        result = replace(result, world=world)
    if settings.dynamics_needed and (not single or determined is None):
        force, moment, torques = split_values(model, wrenches_from_table(model, q, table))
        complete = known.all(axis=-1)
        if not single:
            torques = np.where(complete[:, None], torques, np.nan)  # no dynamics where a joint has no state
        if state.method == "observer":
            external = np.full_like(torques, np.nan)  # the observer's, at the newest samples
        else:
            model_torque = torques + state.effort.friction(qd) + state.effort.rotor_torque(qdd)
            external = state.effort.motor(efforts) - model_torque
        dynamics = Dynamics(model.joint_names, q, qd, torques, external, force, moment)
        contact = None
        if state.contact is not None and state.method != "observer":
            velocities = dynamics.velocities
            if single:
                contact = state.contact.update(stamps, dynamics.external, velocity=velocities)
            else:
                contact = state.contact.update_many(stamps, dynamics.external, complete, velocity=velocities)
        result = replace(result, dynamics=dynamics, contact=contact)
    return Computed(result, rows, known_in, publish, base_unknown)


def observe_raw(model: RobotModel, settings: NodeSettings, raw: RawStates, state: ComputeState) -> Observation | None:
    """The momentum observer at raw samples (one or a batch, in stamp order): external torques,
    the contact state and the contact wrench; None when the observer does not give them."""
    if state.observer is None or state.method != "observer":
        return None
    external, filtered, fast = observe(model, raw, state.effort, state.observer)
    still = state.effort.still(filtered)
    contact = None
    if state.contact is not None:  # on the fast observer's own estimate (see the observer's module)
        slack = settings.contact_static_friction * state.effort.static_friction(filtered)
        if raw.single:
            if np.isfinite(fast).any():
                contact = state.contact.update(raw.stamps, fast, slack, bool(still), raw.qd)
            else:
                state.contact.unseen()
        else:
            usable = np.isfinite(fast).any(axis=-1)
            contact = state.contact.update_many(raw.stamps, fast, usable, slack, still, raw.qd)
    wrench = None
    if settings.contact_link and settings.contact_link in model.link_index:
        wrench = wrench_at_link(model, raw.q, external, settings.contact_link)
    return Observation(
        raw.stamps, model.joint_names, raw.q, raw.qd, external, contact, wrench, settings.contact_link, still
    )


def imu_covariances(
    model: RobotModel, table: np.ndarray, acceleration_std: np.ndarray, links: tuple[str, ...]
) -> dict[str, np.ndarray]:
    """Each link's linear-acceleration covariance (..., 3, 3), link frame, from the joints'
    acceleration standard deviations (..., n) through the link's Jacobian: J diag(std^2) J^T (the
    joint accelerations' errors taken as independent; the velocities' errors left out). NaN where
    a joint that moves the link has no standard deviation."""
    out = {}
    for link in links:
        index = model.link_index.get(link)
        if index is None:
            continue
        jacobian = jacobian_from_table(model, table, index)[..., 0:3, :]  # root axes
        rotation = table[..., index, SLICES["rotation"]].reshape(*table.shape[:-2], 3, 3)
        in_link = np.swapaxes(rotation, -1, -2) @ jacobian
        weighted = in_link * np.square(acceleration_std)[..., None, :]
        out[link] = weighted @ np.swapaxes(in_link, -1, -2)
    return out
