"""The node's core, with no transport: joint states in, messages to publish out.

:class:`Pipeline` holds the model (from the ``robot_description`` parameter or topic, replaceable at
run time) and the streaming estimator. The rclpy node, the no-ROS DDS node and the tests feed it
the fields of incoming messages and publish what it returns, so every runtime behaves the same.
Nothing here raises on bad input: it is dropped and logged (throttled).
"""

from __future__ import annotations

import logging
import re
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from neforward_ros import messages
from neforward_ros.derivatives import JointEstimate, StreamingEstimator
from neforward_ros.errors import ModelError
from neforward_ros.logs import LogFunction, ThrottledLog
from neforward_ros.model import RobotModel, load_model
from neforward_ros.parameters import NodeSettings
from neforward_ros.recursion import LinkKinematics, forward_recursion

# Topic names, relative as ROS 2 conventions ask (namespaces and remapping apply).
JOINT_STATES = "joint_states"
JOINT_STATES_ACCEL = "joint_states_accel"
ROBOT_DESCRIPTION = "robot_description"
LINK_STATES = "~/link_states"
COM_STATES = "~/com_states"
MARKERS = "~/markers"

_TOKEN = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


@dataclass(frozen=True)
class Output:
    """A topic the node publishes: relative name and ROS 2 type (``pkg/msg/Type``)."""

    topic: str
    type: str


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


@dataclass(frozen=True)
class TrajectoryPoint:
    """One trajectory_msgs/JointTrajectoryPoint: positions, velocities, accelerations, time_from_start."""

    positions: Sequence[float]
    velocities: Sequence[float]
    accelerations: Sequence[float]
    time_from_start_ns: int = 0


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
        for link in (*settings.accel_links, *settings.imu_links):
            if not _TOKEN.match(link):
                raise ModelError(f"link {link!r} cannot be part of a ROS 2 topic name (letters, digits, _)")
        if settings.robot_description:
            self.set_model(load_model(settings.robot_description, root_link=settings.root_link), "parameter")
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
            model = load_model(urdf, root_link=self.settings.root_link)
        except Exception as exc:  # ModelError, or a URDF parser that cannot be imported
            kept = "keeping the previous model" if self.model is not None else "still waiting for a valid one"
            self._log.log(logging.ERROR, f"invalid robot description from the {source}: {exc}; {kept}")
            return False
        self.set_model(model, source)
        return True

    def set_model(self, model: RobotModel, source: str = "caller") -> None:
        """Use ``model`` from now on; joint histories restart."""
        missing = [
            link for link in (*self.settings.accel_links, *self.settings.imu_links) if link not in model.link_index
        ]
        if missing:
            self._log.log(
                logging.ERROR,
                f"accel_links/imu_links name links that robot {model.name!r} does not have: {', '.join(missing)}; "
                "nothing is published for them",
            )
        self.model = model
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
        """Every topic published with these settings (known before the model arrives)."""
        settings = self.settings
        return output_list(settings.accel_links, settings.imu_links, settings.publish_markers)

    def messages(self, result: Result) -> list[tuple[str, dict[str, Any]]]:
        """(topic, message contents) for every output of one result."""
        settings = self.settings
        prefix = settings.frame_prefix
        out: list[tuple[str, dict[str, Any]]] = [
            (LINK_STATES, messages.link_states(result, prefix)),
            (COM_STATES, messages.com_states(result, prefix)),
        ]
        out += per_link_messages(result, settings.accel_links, settings.imu_links, prefix)
        if settings.publish_markers:
            out.append((MARKERS, messages.markers(result, prefix, settings.marker_scale)))
        return out

    # -- input ------------------------------------------------------------------------------

    def on_joint_state(
        self,
        stamp_ns: int,
        names: Sequence[str],
        positions: Sequence[float],
        velocities: Sequence[float] = (),
        *,
        receive_ns: int | None = None,
    ) -> list[Result]:
        """A sensor_msgs/JointState's fields; returns the results it completes (see the estimator's modes)."""
        if self._estimator is None:
            self._log.every("no-model", logging.WARNING, "joint states dropped: no robot model yet")
            return []
        try:
            estimates = self._estimator.update(stamp_ns, names, positions, velocities, receive_ns=receive_ns)
            return [r for r in (self._result(e) for e in estimates) if r is not None]
        except Exception as exc:
            self._log.every("internal", logging.ERROR, f"joint state dropped: {type(exc).__name__}: {exc}")
            return []

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

    def ages(self, now_ns: int | None = None) -> dict[str, float]:
        """Seconds since each joint's newest sample (inf if none)."""
        if self._estimator is None or self.model is None:
            return {}
        return dict(zip(self.model.joint_names, self._estimator.ages(now_ns).tolist(), strict=True))

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
        state = np.full((3, len(model.joint_names)), np.nan)
        ignored = set(model.mimic_joint_names)
        for k, name in enumerate(names):
            j = model.joint_index.get(name)
            if j is None:
                if name not in ignored:
                    self._log.once(("unknown", name), logging.WARNING, f"joint trajectory names unknown joint {name!r}")
                continue
            state[:, j] = [float(f[k]) for f in fields]
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
        )
        return self._result(estimate)

    def _result(self, estimate: JointEstimate) -> Result | None:
        model = self.model
        assert model is not None
        if not estimate.all_ready:
            waiting = [n for n, ok in zip(model.joint_names, estimate.ready, strict=True) if not ok]
            self._log.every(
                "not-ready",
                logging.WARNING,
                f"nothing published: no recent state for joint(s) {', '.join(waiting)} "
                "(never received, just restarted, or silent for longer than max_gap)",
            )
            return None
        in_link = forward_recursion(
            model, estimate.positions, estimate.velocities, estimate.accelerations, gravity=self.settings.gravity
        )
        return make_result(model, estimate.stamp_ns, in_link, estimate)


def output_list(accel_links: Sequence[str], imu_links: Sequence[str], publish_markers: bool) -> list[Output]:
    """The node's outputs, relative names: link_states, com_states, per-link topics, markers."""
    out = [Output(LINK_STATES, messages.LINK_STATES_TYPE), Output(COM_STATES, messages.LINK_STATES_TYPE)]
    for link in accel_links:
        out += [Output(f"~/{link}/accel", messages.ACCEL_TYPE), Output(f"~/{link}/twist", messages.TWIST_TYPE)]
    out += [Output(f"~/{link}/imu", messages.IMU_TYPE) for link in imu_links]
    if publish_markers:
        out.append(Output(MARKERS, messages.MARKERS_TYPE))
    return out


def per_link_messages(
    result: Result, accel_links: Sequence[str], imu_links: Sequence[str], frame_prefix: str
) -> list[tuple[str, dict[str, Any]]]:
    """(topic, contents) of the per-link outputs of one result, in :func:`output_list` order.

    Links the result's model does not have are left out (the pipeline logs them once).
    """
    out: list[tuple[str, dict[str, Any]]] = []
    for link in accel_links:
        if link in result.link_names:
            k = result.link_names.index(link)
            out.append((f"~/{link}/accel", messages.accel_stamped(result, k, frame_prefix)))
            out.append((f"~/{link}/twist", messages.twist_stamped(result, k, frame_prefix)))
    for link in imu_links:
        if link in result.link_names:
            out.append((f"~/{link}/imu", messages.imu(result, result.link_names.index(link), frame_prefix)))
    return out


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
        orientation_in_root=messages.quaternions(rotation),
        joints=joints,
    )
