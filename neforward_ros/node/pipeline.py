"""The node's core, with no transport: messages in, results to publish out.

:class:`Pipeline` holds the model (from the ``robot_description`` parameter or topic, replaceable at
run time), the live inputs (the streaming estimator and, for a moving base, the base tracker:
:mod:`neforward_ros.computation.live_inputs`) and the computation's state, and turns each result of
:func:`neforward_ros.computation.compute.compute` into message bytes. The rclpy node, the no-ROS DDS
node and the tests feed it the fields of incoming messages and publish what it returns, so every
runtime behaves the same; the bag tool calls the same computation on a recording. Nothing here
raises on bad input: it is dropped and logged (throttled).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from neforward_ros.computation.base_motion import BaseMessage
from neforward_ros.computation.compute import Computed, ComputeState, compute, observe_raw, observer_wanted
from neforward_ros.computation.inputs import JointStates, LinkMotion
from neforward_ros.computation.live_inputs import Inputs, LiveInputs
from neforward_ros.computation.result import Observation, Result
from neforward_ros.errors import ModelError
from neforward_ros.estimation.joint_messages import JointMessageReader
from neforward_ros.interface import encoder, messages
from neforward_ros.interface.names import is_token
from neforward_ros.interface.topics import ROBOT_DESCRIPTION, Output, output_list
from neforward_ros.kinematics.backward_kernel import backward_of
from neforward_ros.kinematics.forward_kernel import kernel_of
from neforward_ros.kinematics.joint_space_kernel import momentum_of
from neforward_ros.logs import LogFunction, ThrottledLog
from neforward_ros.model import RobotModel, load_model
from neforward_ros.parameters.settings import NodeSettings


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
        self._inputs: LiveInputs | None = None
        self._state: ComputeState | None = None
        self._encoder: encoder.Encoder | None = None
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
        """Use ``model`` from now on (with the ``payload.*`` point mass); joint histories restart."""
        settings = self.settings
        model = settings.model_of(model)
        missing = [link for link in settings.named_links if link not in model.link_index]
        if missing:
            self._log.log(
                logging.ERROR,
                f"accel_links/imu_links/wrench_links/contact.link/payload.link name links that robot {model.name!r} "
                f"does not have: {', '.join(missing)}; nothing is published for them (or no payload is added)",
            )
        for parameter, names in settings.named_joints:
            unknown = [name for name in names if name not in model.joint_index]
            if unknown:
                self._log.log(
                    logging.ERROR,
                    f"{parameter} name joints that robot {model.name!r} does not have (or mimic joints, which "
                    f"follow their leader): {', '.join(unknown)}; ignored",
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
        # Generate the recursions now, not while the first joint states wait; compile them in a thread
        # (the node takes the compiled kernels once they are ready: the same numbers, faster).
        kernel_of(model).native.get(start=True)
        if settings.dynamics_needed:
            backward_of(model).native.get(start=True)
        if observer_wanted(settings):
            momentum_of(model).native.get(start=True)
        self.model = model
        self._supplied_names = JointMessageReader(model.joint_names, model.mimic_joint_names, self._log)
        self._inputs = LiveInputs(model, settings, self._log_function, raw=observer_wanted(settings))
        self._state = ComputeState.new(model, settings, self._log_function)
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
            bool(settings.contact_link),
            settings.publish_joint_estimates,
        )

    def messages(self, result: Result | Observation) -> list[tuple[str, dict[str, Any]]]:
        """(topic, message contents) for every output of one result or observation."""
        if isinstance(result, Observation):
            return messages.observation_messages(result, self.settings)
        return messages.all_messages(result, self.settings)

    def encode(self, result: Result | Observation) -> list[tuple[str, bytes]]:
        """(topic, CDR bytes) for every output of one result or observation: what the runtimes publish."""
        if self._encoder is None or self._encoder.settings is not self.settings:
            self._encoder = encoder.Encoder(self.settings)
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
    ) -> list[Result | Observation]:
        """A sensor_msgs/JointState's fields; returns what it completes: the momentum observer's
        observation at its stamp (when the observer gives the external torques), then the results
        the estimator releases (see its modes)."""
        if self._inputs is None:
            self._log.every("no-model", logging.WARNING, "joint states dropped: no robot model yet")
            return []
        try:
            inputs = self._inputs.joint_state(stamp_ns, names, positions, velocities, efforts, receive_ns)
        except Exception as exc:
            self._log.every("internal", logging.ERROR, f"joint state dropped: {type(exc).__name__}: {exc}")
            return []
        return [*self._observations(), *self._results(inputs)]

    def _observations(self) -> list[Observation]:
        """The momentum observer at the newest samples (published before the estimator's lagged results)."""
        live, state, model = self._inputs, self._state, self.model
        assert live is not None and state is not None and model is not None
        raw = live.take_raw()
        if live.velocities is not None:
            state.decide(live.velocities)
        out = []
        for states in raw:
            try:
                observation = observe_raw(model, self.settings, states, state)
            except Exception as exc:
                self._log.every("internal", logging.ERROR, f"external torques dropped: {type(exc).__name__}: {exc}")
                continue
            if observation is not None:
                out.append(observation)
        return out

    def on_base(self, message: BaseMessage) -> list[Result]:
        """A base sensor_msgs/Imu or nav_msgs/Odometry (``base.source``); returns the results of the
        joint states it lets out."""
        if self._inputs is None:
            return []
        try:
            inputs = self._inputs.base(message)
        except Exception as exc:
            self._log.every("internal", logging.ERROR, f"base message dropped: {type(exc).__name__}: {exc}")
            return []
        return self._results(inputs)

    def _results(self, inputs: list[Inputs]) -> list[Result]:
        out = []
        for states, base in inputs:
            try:
                result = self._compute(states, base)
            except Exception as exc:
                self._log.every("internal", logging.ERROR, f"joint state dropped: {type(exc).__name__}: {exc}")
                continue
            if result is not None:
                out.append(result)
        return out

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
        n = len(model.joint_names)
        ready = np.ones(n, dtype=bool)
        return self._compute(JointStates(stamp, state[0], state[1], state[2], ready, ~ready, efforts), None)

    def _compute(self, states: JointStates, base: LinkMotion | None) -> Result | None:
        """The computation on one stamp, and what the node says when some joints have no estimate."""
        model, state = self.model, self._state
        assert model is not None and state is not None
        computed = compute(model, self.settings, states, base, state)
        if not computed.known.all() or computed.base_unknown:
            self._say_why(computed, base)
        return computed.result

    def _say_why(self, computed: Computed, base: LinkMotion | None) -> None:
        model = self.model
        assert model is not None
        why = "never received, silent for longer than max_gap, or warming up (see the estimator's log)"
        waiting = ", ".join(n for n, ok in zip(model.joint_names, computed.known, strict=True) if not ok)
        if not computed.publish and not computed.base_unknown:
            self._log.every(
                "not-ready", logging.WARNING, f"nothing published: no estimate for joint(s) {waiting} ({why})"
            )
        elif computed.base_unknown and base is not None:
            unknown = base.link not in model.link_index
            reason = "not a link of the model" if unknown else "a joint above it has no estimate"
            self._log.every(
                "base-link",
                logging.WARNING,
                f"nothing published: the base source measures link {base.link!r}, {reason} (set base.link)",
            )
        elif computed.result is not None:
            self._log.every(
                "partial",
                logging.WARNING,
                f"publishing {len(computed.result.link_names)} of {len(model.link_names)} links: no estimate for "
                f"joint(s) {waiting} ({why}); the links they move are left out",
            )
