"""The node's core, with no transport: joint states in, messages to publish out.

:class:`Pipeline` holds the model (from the ``robot_description`` parameter or topic, replaceable at
run time) and the streaming estimator. The rclpy node, the no-ROS DDS node and the tests feed it
the fields of incoming messages and publish what it returns, so every runtime behaves the same.
Nothing here raises on bad input: it is dropped and logged (throttled).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from neforward_ros.base import base_from_link, link_pose
from neforward_ros.dynamics import split_values, wrenches_from_table
from neforward_ros.errors import ModelError
from neforward_ros.estimation.estimate import JointEstimate
from neforward_ros.estimation.joint_messages import JointMessageReader
from neforward_ros.estimation.stream import StreamingEstimator
from neforward_ros.kernel import kernel_of
from neforward_ros.logs import LogFunction, ThrottledLog
from neforward_ros.model import RobotModel, load_model
from neforward_ros.node import messages
from neforward_ros.node.base_source import Aligner, BaseMessage, BaseTracker, LinkSample
from neforward_ros.node.contact import ContactDetector
from neforward_ros.node.names import is_token
from neforward_ros.node.policy import apply_policy, hold_vector
from neforward_ros.node.result import Dynamics, Result, make_result
from neforward_ros.node.settings import NodeSettings
from neforward_ros.node.topics import ROBOT_DESCRIPTION, Output, output_list
from neforward_ros.recursion import kinematics_table, root_state
from neforward_ros.rotations import rotation_matrix


@dataclass(frozen=True)
class TrajectoryPoint:
    """One trajectory_msgs/JointTrajectoryPoint: positions, velocities, accelerations, time_from_start,
    and efforts (may be empty: then none is measured)."""

    positions: Sequence[float]
    velocities: Sequence[float]
    accelerations: Sequence[float]
    time_from_start_ns: int = 0
    efforts: Sequence[float] = ()


class Pipeline:
    """Joint states -> link kinematics -> message contents.

    Args:
        settings: validated parameters.
        log: ``log(level, message)``; the Python logger ``neforward_ros`` by default.

    Raises:
        ModelError: the ``robot_description`` parameter is set and is not a valid URDF (a start-up
            error: the node should exit with that message).
    """

    def __init__(self, settings: NodeSettings, *, log: LogFunction | None = None) -> None:
        self.settings = settings
        self._log_function = log
        self._log = ThrottledLog(log)
        self.model: RobotModel | None = None
        self._estimator: StreamingEstimator | None = None
        self._encoder: messages.Encoder | None = None
        self._hold = np.zeros(0)
        self._effort_scale = self._effort_offset = np.zeros(0)
        self._contact: ContactDetector | None = None
        self._aligner: Aligner | None = None
        if settings.base_source != "fixed":
            tracker = BaseTracker(settings.base_source, settings.estimator, settings.gravity, log)
            self._aligner = Aligner(tracker, settings.base_max_delay, log)
        for link in (*settings.accel_links, *settings.imu_links, *settings.wrench_links):
            if not is_token(link):
                raise ModelError(f"link {link!r} cannot be part of a ROS 2 topic name (letters, digits, _)")
        if settings.robot_description:
            self.set_model(load_model(settings.robot_description, root_link=settings.root_link, log=log), "parameter")
        else:
            self._log.once(
                "waiting",
                logging.INFO,
                f"no robot_description parameter: waiting for the model on the {ROBOT_DESCRIPTION} topic",
            )

    # -- model ------------------------------------------------------------------------------

    def set_description(self, urdf: str, source: str = f"{ROBOT_DESCRIPTION} topic") -> bool:
        """Replace the model with one parsed from URDF text. An invalid one is logged and the previous
        model kept. Returns whether the model was replaced."""
        try:
            model = load_model(urdf, root_link=self.settings.root_link, log=self._log_function)
        except Exception as exc:  # ModelError, or a URDF parser that cannot be imported
            kept = "keeping the previous model" if self.model is not None else "still waiting for a valid one"
            self._log.log(logging.ERROR, f"invalid robot description from the {source}: {exc}; {kept}")
            return False
        self.set_model(model, source)
        return True

    def set_model(self, model: RobotModel, source: str = "caller") -> None:
        """Use ``model`` from now on; joint histories restart."""
        settings = self.settings
        missing = [link for link in settings.named_links if link not in model.link_index]
        if missing:
            self._log.log(
                logging.ERROR,
                f"accel_links/imu_links/wrench_links name links that robot {model.name!r} does not have: "
                f"{', '.join(missing)}; nothing is published for them",
            )
        for parameter, names in settings.named_joints:
            unknown = [name for name in names if name not in model.joint_index]
            if unknown:
                self._log.log(
                    logging.ERROR,
                    f"{parameter} name joints that robot {model.name!r} does not have (or mimic joints, which "
                    f"follow their leader): {', '.join(unknown)}; ignored",
                )
        self._hold = hold_vector(model.joint_names, settings.hold_positions)
        self._effort_scale = np.array([settings.effort_scale.get(n, 1.0) for n in model.joint_names])
        self._effort_offset = np.array([settings.effort_offset.get(n, 0.0) for n in model.joint_names])
        self._contact = (
            ContactDetector(
                np.array([settings.contact_thresholds.get(n, np.nan) for n in model.joint_names]),
                settings.contact_debounce,
                model.joint_names,
                self._log,
            )
            if settings.contact_thresholds
            else None
        )
        if settings.dynamics_needed:
            for warning in model.inertia_warnings:
                self._log.log(logging.WARNING, warning)
        if model.floating_base and settings.base_source == "fixed":
            self._log.log(
                logging.WARNING,
                f"robot {model.name!r} has a floating base (joint {model.floating_base!r}), but base.source is fixed: "
                "its root link is taken to be at rest; set base.source to imu or odometry for a moving base",
            )
        if settings.base_link and settings.base_link not in model.link_index:
            self._log.log(logging.ERROR, f"base.link {settings.base_link!r} is not a link of robot {model.name!r}")
        kernel_of(model)  # generate the recursion now, not while the first joint states wait
        self.model = model
        self._supplied_names = JointMessageReader(model.joint_names, model.mimic_joint_names, self._log)
        self._estimator = StreamingEstimator(
            model.joint_names,
            wrap=model.continuous_columns,
            ignored_names=model.mimic_joint_names,
            settings=self.settings.estimator,
            log=self._log_function,
        )
        self._log.log(
            logging.INFO,
            f"model {model.name!r} from the {source}: {len(model.link_names)} links, {len(model.joint_names)} joints, "
            f"root {model.root_link!r}",
        )

    def update_settings(self, settings: NodeSettings) -> None:
        """Use new values of the settings that may change at run time (gravity, frame_prefix,
        marker_scale); the model and the estimator's histories are kept."""
        self.settings = replace(
            self.settings,
            gravity=settings.gravity,
            frame_prefix=settings.frame_prefix,
            marker_scale=settings.marker_scale,
        )

    # -- topics -----------------------------------------------------------------------------

    def outputs(self) -> list[Output]:
        """Every topic published with these settings (known before the model arrives); once a model
        is loaded, per-link topics only for links it has (the others were reported as errors)."""
        settings = self.settings

        def known(links: tuple[str, ...]) -> tuple[str, ...]:
            return links if self.model is None else tuple(k for k in links if k in self.model.link_index)

        return output_list(
            known(settings.accel_links),
            known(settings.imu_links),
            settings.publish_markers,
            settings.publish_torques,
            known(settings.wrench_links),
            bool(settings.contact_thresholds),
            settings.world_states,
        )

    def messages(self, result: Result) -> list[tuple[str, dict[str, Any]]]:
        """(topic, message contents) for every output of one result."""
        return messages.all_messages(result, self.settings)

    def encode(self, result: Result) -> list[tuple[str, bytes]]:
        """(topic, CDR bytes) for every output of one result: what the runtimes publish."""
        if self._encoder is None or self._encoder.settings is not self.settings:
            self._encoder = messages.Encoder(self.settings)
        return self._encoder.encode(result)

    # -- input ------------------------------------------------------------------------------

    def on_joint_state(
        self,
        stamp_ns: int,
        names: Sequence[str],
        positions: Sequence[float],
        velocities: Sequence[float] = (),
        efforts: Sequence[float] = (),
        *,
        receive_ns: int | None = None,
    ) -> list[Result]:
        """A sensor_msgs/JointState's fields; returns the results it completes (see the estimator's modes)."""
        if self._estimator is None:
            self._log.every("no-model", logging.WARNING, "joint states dropped: no robot model yet")
            return []
        try:
            estimates = self._estimator.update(stamp_ns, names, positions, velocities, efforts, receive_ns=receive_ns)
            if self._aligner is not None:  # each waits for the base motion at its stamp
                self._aligner.add(estimates)
                return self._aligned()
            return [r for r in (self._result(e) for e in estimates) if r is not None]
        except Exception as exc:
            self._log.every("internal", logging.ERROR, f"joint state dropped: {type(exc).__name__}: {exc}")
            return []

    def on_base(self, message: BaseMessage) -> list[Result]:
        """A base sensor_msgs/Imu or nav_msgs/Odometry (``base.source``); returns the results of the
        joint states it lets out."""
        if self._aligner is None:
            return []
        try:
            self._aligner.tracker.on_message(message)
            return self._aligned()
        except Exception as exc:
            self._log.every("internal", logging.ERROR, f"base message dropped: {type(exc).__name__}: {exc}")
            return []

    def _aligned(self) -> list[Result]:
        assert self._aligner is not None
        return [r for r in (self._result(e, sample) for e, sample in self._aligner.ready()) if r is not None]

    def on_joint_trajectory(
        self,
        stamp_ns: int,
        joint_names: Sequence[str],
        points: Sequence[TrajectoryPoint],
        *,
        receive_ns: int | None = None,
    ) -> list[Result]:
        """Supplied states (trajectory_msgs/JointTrajectory): each point's q, qd, qdd used as given,
        stamped header.stamp + time_from_start (a zero header.stamp means the receive time)."""
        if self.model is None:
            self._log.every("no-model", logging.WARNING, "joint trajectories dropped: no robot model yet")
            return []
        if stamp_ns == 0 and receive_ns is not None:
            stamp_ns = receive_ns
        results = []
        for point in points:
            try:
                result = self._supplied(stamp_ns + point.time_from_start_ns, joint_names, point)
            except Exception as exc:
                self._log.every("internal", logging.ERROR, f"joint trajectory dropped: {type(exc).__name__}: {exc}")
                continue
            if result is not None:
                results.append(result)
        return results

    # -- computation ------------------------------------------------------------------------

    def _supplied(self, stamp: int, names: Sequence[str], point: TrajectoryPoint) -> Result | None:
        model = self.model
        assert model is not None
        count = len(names)
        fields = (point.positions, point.velocities, point.accelerations)
        if any(len(f) != count for f in fields):
            self._log.every(
                "supplied-length",
                logging.WARNING,
                f"joint trajectory point rejected: {count} joint names but "
                f"{'/'.join(str(len(f)) for f in fields)} positions/velocities/accelerations",
            )
            return None
        mapped = self._supplied_names.names(names)
        if mapped.duplicate is not None:
            self._log.every(
                "supplied-duplicate",
                logging.WARNING,
                f"joint trajectory point rejected: it names joint {mapped.duplicate!r} more than once",
            )
            return None
        state = np.full((3, len(model.joint_names)), np.nan)
        efforts = np.full(len(model.joint_names), np.nan)
        with_effort = len(point.efforts) == count
        for k, j in mapped.pairs:
            state[:, j] = [float(f[k]) for f in fields]
            if with_effort:
                efforts[j] = float(point.efforts[k])
        if not np.all(np.isfinite(state)):
            missing = [n for n, ok in zip(model.joint_names, np.isfinite(state).all(0), strict=True) if not ok]
            self._log.every(
                "supplied-missing",
                logging.WARNING,
                "joint trajectory point rejected: no finite position, velocity and acceleration for "
                + ", ".join(missing),
            )
            return None
        estimate = JointEstimate(
            stamp_ns=stamp,
            segment=0,
            positions=state[0],
            velocities=state[1],
            accelerations=state[2],
            ages=np.zeros(len(model.joint_names)),
            ready=np.ones(len(model.joint_names), dtype=bool),
            efforts=efforts,
        )
        return self._result(estimate)

    def _result(self, estimate: JointEstimate, base: LinkSample | None = None) -> Result | None:
        """The recursion on one estimate, under the publish policy (:mod:`.policy`) when some joints
        have none; with the base source's sample at its stamp for a moving base."""
        model = self.model
        assert model is not None
        settings = self.settings
        q, qd, qdd = estimate.positions, estimate.velocities, estimate.accelerations
        determined = None
        if not estimate.all_ready:
            silent = estimate.ages > settings.estimator.max_gap
            published = apply_policy(settings.publish_policy, q, qd, qdd, estimate.ready, silent, self._hold)
            if not published.known.all():
                waiting = ", ".join(n for n, ok in zip(model.joint_names, published.known, strict=True) if not ok)
                why = "never received, silent for longer than max_gap, or warming up (see the estimator's log)"
                if not published.publish:
                    self._log.every(
                        "not-ready", logging.WARNING, f"nothing published: no estimate for joint(s) {waiting} ({why})"
                    )
                    return None
                determined = model.determined_links(published.known)
                self._log.every(
                    "partial",
                    logging.WARNING,
                    f"publishing {int(determined.sum())} of {len(determined)} links: no estimate for joint(s) "
                    f"{waiting} ({why}); the links they move are left out",
                )
            q, qd, qdd = published.q, published.qd, published.qdd
        # The estimator's and the supplied states are finite by construction: no input checks here.
        world = None
        if base is None:
            root = root_state(settings.gravity)
        else:
            moving = self._base_motion(q, qd, qdd, base, determined)
            if moving is None:
                return None
            root, world = moving
        table = kinematics_table(model, q, qd, qdd, root)
        result = make_result(model, estimate.stamp_ns, table, determined)
        if world is not None:
            result = replace(result, world=world)
        if settings.dynamics_needed and determined is None:
            result = self._with_dynamics(result, estimate, q, qd, table)
        return result

    def _base_motion(
        self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, sample: LinkSample, determined: np.ndarray | None
    ) -> tuple[tuple[float, ...], tuple[np.ndarray, np.ndarray] | None] | None:
        """The root's state from the base source's link motion, and the root's pose in the world
        (rotation root -> world, position) when the source gives orientation; None (logged) when the
        measured link is unknown or not determined."""
        model = self.model
        assert model is not None and self._aligner is not None
        link = self.settings.base_link or self._aligner.tracker.frame_id
        index = model.link_index.get(link)
        if index is None or (determined is not None and not determined[index]):
            why = "not a link of the model" if index is None else "a joint above it has no estimate"
            self._log.every(
                "base-link",
                logging.WARNING,
                f"nothing published: the base source measures link {link!r}, {why} (set base.link)",
            )
            return None
        motion = base_from_link(
            model,
            link,
            q,
            qd,
            qdd,
            omega=sample.omega,
            alpha=sample.alpha,
            specific_force=sample.specific_force,
            velocity=sample.velocity,
        )
        world = None
        if sample.orientation is not None:
            # root -> world = (link -> world) (link -> root)^T, at these joint states
            rotation, position = link_pose(model, q, index)
            world_link = rotation_matrix(sample.orientation)
            world_root = world_link @ rotation.T
            origin = np.zeros(3) if sample.position is None else sample.position - world_root @ position
            world = (world_root, origin)
        return motion.root(None), world

    def _with_dynamics(
        self, result: Result, estimate: JointEstimate, q: np.ndarray, qd: np.ndarray, table: np.ndarray
    ) -> Result:
        """The result with its joint torques, joint wrenches and contact state (every joint known)."""
        model = self.model
        assert model is not None
        force, moment, torques = split_values(model, wrenches_from_table(model, q, table))
        efforts = estimate.efforts if estimate.efforts is not None else np.full(len(model.joint_names), np.nan)
        measured = self._effort_scale * efforts + self._effort_offset
        dynamics = Dynamics(model.joint_names, q, qd, torques, measured, force, moment)
        contact = self._contact.update(estimate.stamp_ns, dynamics.external) if self._contact is not None else None
        return replace(result, dynamics=dynamics, contact=contact)
