"""What ``neforward bag`` computes and writes."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from neforward_ros.errors import InputError
from neforward_ros.estimation.fit import DEFAULT_ORDER, DEFAULT_WINDOW
from neforward_ros.estimation.stream import DEFAULT_MAX_GAP, VELOCITY_SOURCES
from neforward_ros.node.base_source import BASE_SOURCES
from neforward_ros.node.policy import PUBLISH_POLICIES
from neforward_ros.recursion import DEFAULT_GRAVITY

STORAGES = ("mcap", "sqlite3")


@dataclass(frozen=True)
class BagOptions:
    """What to compute and write; the defaults are the node's.

    Attributes:
        urdf: URDF file; None takes the model from the recording's robot_description topic.
        root_link: the link whose frame is the root frame; None: the URDF's root (below a floating
            joint, its child).
        joint_states_topic: None picks the recording's sensor_msgs/JointState topic.
        storage: output storage, ``mcap`` or ``sqlite3``.
        accel_links, imu_links: links that also get <link>/accel, <link>/twist and <link>/imu.
        gravity: m/s^2 in the root frame.
        method, window, order: the whole-recording estimator's.
        velocity_source: ``auto`` uses recorded velocities where every sample of a joint has one.
        max_gap: s; stamps further than this from a joint's samples get no output for it.
        frame_prefix: prepended to frame_ids.
        publish_policy: when some joints have no estimate at a stamp: ``partial`` writes the links
            every joint above which has one, ``wait`` writes nothing, ``hold`` holds joints with no
            sample within max_gap (or none at all) at ``hold_positions`` (others 0), at rest.
        hold_positions: joint name -> position, for ``hold``.
        publish_torques: write joint_torques and (where efforts are recorded) external_torques.
        wrench_links: links that also get a <link>/wrench topic.
        effort_scale, effort_offset: joint name -> measured = scale * effort + offset.
        contact_thresholds: joint name -> |external torque| threshold: writes contact.
        contact_debounce: s.
        base_source: ``fixed``, ``imu`` or ``odometry``: the root's motion from a topic of the recording.
        base_topic: that topic; None picks the recording's one topic of that type.
        base_link: the link the source measures; "" for the messages' frame id.
        world_frame: frame id of world_link_states (a source with orientation); "" for none.
    """

    urdf: str | None = None
    root_link: str | None = None
    joint_states_topic: str | None = None
    storage: str = "mcap"
    accel_links: tuple[str, ...] = ()
    imu_links: tuple[str, ...] = ()
    gravity: tuple[float, float, float] = DEFAULT_GRAVITY
    method: str = "polyfit"
    window: float = DEFAULT_WINDOW
    order: int = DEFAULT_ORDER
    velocity_source: str = "auto"
    max_gap: float = DEFAULT_MAX_GAP
    frame_prefix: str = ""
    publish_policy: str = "partial"
    hold_positions: Mapping[str, float] = field(default_factory=dict)
    publish_torques: bool = False
    wrench_links: tuple[str, ...] = ()
    effort_scale: Mapping[str, float] = field(default_factory=dict)
    effort_offset: Mapping[str, float] = field(default_factory=dict)
    contact_thresholds: Mapping[str, float] = field(default_factory=dict)
    contact_debounce: float = 0.02
    base_source: str = "fixed"
    base_topic: str | None = None
    base_link: str = ""
    world_frame: str = ""

    @property
    def dynamics_needed(self) -> bool:
        return bool(self.publish_torques or self.wrench_links or self.contact_thresholds)


def check_options(options: BagOptions) -> None:
    if options.storage not in STORAGES:
        raise InputError(f"unknown storage {options.storage!r}; choose {' or '.join(STORAGES)}")
    if options.velocity_source not in VELOCITY_SOURCES:
        raise InputError(f"unknown velocity_source {options.velocity_source!r}")
    if options.publish_policy not in PUBLISH_POLICIES:
        raise InputError(f"unknown publish policy {options.publish_policy!r}; choose {', '.join(PUBLISH_POLICIES)}")
    if options.base_source not in BASE_SOURCES:
        raise InputError(f"unknown base source {options.base_source!r}; choose {', '.join(BASE_SOURCES)}")
    if options.method not in ("polyfit", "difference"):
        raise InputError(
            f"the bag tool's estimator is polyfit or difference (whole-recording fits), not {options.method!r}: "
            "a recording has every sample at hand, so the low-delay estimators have nothing to offer there"
        )
