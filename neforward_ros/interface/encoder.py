"""The CDR bytes of every output of a result: what both runtimes publish and the bag tool records."""

from __future__ import annotations

from neforward_ros.computation.result import Observation, Result
from neforward_ros.interface.messages import (
    com_states,
    dynamics_messages,
    link_states,
    markers,
    observation_messages,
    per_link_messages,
    world_link_states,
)
from neforward_ros.interface.topics import (
    COM_STATES,
    LINK_STATES,
    LINK_STATES_TYPE,
    MARKERS,
    WORLD_LINK_STATES,
    output_list,
)
from neforward_ros.parameters.settings import NodeSettings
from neforward_ros.wire import cdr


class Templates:
    """link_states and com_states templates (:class:`neforward_ros.wire.cdr.MultiDofTemplate`), one
    pair per set of links published: the whole model, or the links determined while some joints
    have no estimate. Made on first use; the :data:`KEPT` most recent sets are kept."""

    KEPT = 16

    def __init__(self, frame_prefix: str) -> None:
        self.frame_prefix = frame_prefix
        self._pairs: dict[tuple[str, tuple[str, ...]], tuple[cdr.MultiDofTemplate, cdr.MultiDofTemplate]] = {}

    def __call__(self, result: Result) -> tuple[cdr.MultiDofTemplate, cdr.MultiDofTemplate]:
        key = (result.root_link, result.link_names)
        found = self._pairs.get(key)
        if found is None:
            if len(self._pairs) >= self.KEPT:
                del self._pairs[next(iter(self._pairs))]
            first = result.sample(0) if result.table.ndim == 3 else result
            found = (
                cdr.MultiDofTemplate(cdr.encode(LINK_STATES_TYPE, link_states(first, self.frame_prefix))),
                cdr.MultiDofTemplate(cdr.encode(LINK_STATES_TYPE, com_states(first, self.frame_prefix))),
            )
            self._pairs[key] = found
        return found


class Encoder:
    """The CDR bytes of every output of a result: what the node publishes.

    link_states and com_states, published for every result, are patched into :class:`Templates`
    instead of being built as contents and encoded; the per-link topics and the markers are built
    and encoded. Either way the bytes are those of :func:`all_messages` encoded by
    :func:`neforward_ros.wire.cdr.encode` (tested).
    """

    def __init__(self, settings: NodeSettings) -> None:
        self.settings = settings
        self._types = {output.topic: output.type for output in output_list(
            settings.accel_links, settings.imu_links, settings.publish_markers, settings.publish_torques,
            settings.wrench_links, bool(settings.contact_thresholds), bool(settings.world_frame),
            bool(settings.contact_link), settings.publish_joint_estimates,
        )}  # fmt: skip
        self.templates = Templates(settings.frame_prefix)

    def encode(self, result: Result | Observation) -> list[tuple[str, bytes]]:
        settings = self.settings
        if isinstance(result, Observation):
            return [(t, cdr.encode(self._types[t], c)) for t, c in observation_messages(result, settings)]
        link_template, com_template = self.templates(result)
        stamp = result.stamp_ns
        link_blocks, com_blocks = result.blocks
        out = [
            (LINK_STATES, link_template.encode(stamp, *link_blocks)),
            (COM_STATES, com_template.encode(stamp, *com_blocks)),
        ]
        if settings.world_frame and result.world is not None:
            world = world_link_states(result, settings.world_frame, settings.gravity)
            out.append((WORLD_LINK_STATES, cdr.encode(LINK_STATES_TYPE, world)))
        rest = per_link_messages(result, settings.accel_links, settings.imu_links, settings.frame_prefix)
        if settings.publish_markers:
            rest.append((MARKERS, markers(result, settings.frame_prefix, settings.marker_scale)))
        rest += dynamics_messages(result, settings.publish_torques, settings.wrench_links, settings.frame_prefix)
        out += [(topic, cdr.encode(self._types[topic], contents)) for topic, contents in rest]
        return out
