"""What ``neforward bag`` computes and writes: the node's settings, and what only a recording needs.

Every option of the node applies offline too, from the same parameter table
(:data:`neforward_ros.parameters.settings.PARAMETERS`) and the same params files: ``settings`` is exactly
what the node would run with. The estimator's default (polyfit, fixed lag window / 2) is computed
over the whole recording at once, which gives what the node publishes; any other estimator setting
(causal mode, another lag, kalman) replays the recording through the node's streaming estimator,
message by message.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from neforward_ros.errors import InputError
from neforward_ros.estimation.settings import StreamSettings
from neforward_ros.parameters.settings import NodeSettings, node_settings

STORAGES = ("mcap", "sqlite3")
"""The storages a recording is written in."""


@dataclass(frozen=True)
class BagOptions:
    """What to compute and write.

    Attributes:
        settings: the node's settings (root_link, gravity, estimator, max_gap, velocity_source,
            publish_policy, hold, torques, effort, wrench and contact, base source, world_frame,
            per-link topics, frame_prefix).
        urdf: URDF (or xacro) file; None takes the model from the recording's robot_description topic.
        joint_states_topic: None picks the recording's sensor_msgs/JointState topic.
        base_topic: the recording's base topic (base.source imu or odometry); None: the one topic of
            that type (or ``base.topic``'s, when the recording has several).
        storage: output storage, ``mcap`` or ``sqlite3``.
    """

    settings: NodeSettings = field(default_factory=NodeSettings)
    urdf: str | None = None
    joint_states_topic: str | None = None
    base_topic: str | None = None
    storage: str = "mcap"

    @classmethod
    def from_parameters(cls, values: Mapping[str, Any], **fields: Any) -> BagOptions:
        """Options from node parameter values (validated as the node validates them) and bag fields.

        Raises:
            InputError: as :func:`~neforward_ros.parameters.settings.node_settings`.
        """
        return cls(settings=node_settings(values), **fields)

    @property
    def streamed(self) -> bool:
        """Whether the estimator is replayed message by message (anything but the default fixed lag)."""
        estimator = self.settings.estimator
        return estimator.method == "kalman" or estimator.mode == "causal" or estimator.lag is not None

    @property
    def batch_estimator(self) -> StreamSettings:
        """The whole-recording estimator: the node's polyfit (or difference) with its window and order,
        at a centred fixed lag; also what a moving base's topic is differentiated with."""
        estimator = self.settings.estimator
        method = estimator.method if estimator.method in ("polyfit", "difference") else "polyfit"
        return StreamSettings(
            method=method, window=estimator.window, order=estimator.order, adaptive=estimator.adaptive
        )

    @property
    def dynamics_needed(self) -> bool:
        return self.settings.dynamics_needed


def check_options(options: BagOptions) -> None:
    if options.storage not in STORAGES:
        raise InputError(f"unknown storage {options.storage!r}; choose {' or '.join(STORAGES)}")
    if options.settings.acceleration_source != "estimate":
        raise InputError("acceleration_source supplied: a recording's joint states are estimated, not supplied")
