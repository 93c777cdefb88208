"""Every node option honoured by ``neforward bag``: the bag's link_states for a recording, with the
option given as on the node (``-p``, ``--params``), against the node's own core (the pipeline fed
the same messages one by one), and different from what the defaults give."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from test_bag import PANDA, read_output, record

from neforward_ros.cli import main
from neforward_ros.estimation import native_fit
from neforward_ros.node.pipeline import Pipeline
from neforward_ros.parameters.settings import node_settings
from neforward_ros.wire import cdr
from neforward_ros.wire.rostypes import typestore

LINK_STATES = "/neforward/link_states"

CASES = [
    # (parameters, replayed through the streaming estimator: exactly the node's numbers)
    ({"estimator.mode": "causal"}, True),
    ({"estimator.method": "kalman"}, True),
    ({"estimator.method": "kalman", "estimator.mode": "causal", "estimator.kalman.length_scale": 0.2}, True),
    ({"estimator.lag": 0.04}, True),
    ({"estimator.window": 0.12, "estimator.order": 3}, False),
    ({"velocity_source": "differentiate"}, False),
    ({"root_link": "panda_link3", "frame_prefix": "left/"}, False),
    ({"max_gap": 0.01}, False),
    ({"gravity": [0.0, 0.0, 0.0]}, False),
]


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    # the node and the bag take one fit throughout: the compiled one, once built (where it became ready
    # between the two, run alone, they differed by 1.1e-9 of an acceleration, past the 1e-9 compared)
    native_fit.FIT.get(wait=True)
    path = tmp_path_factory.mktemp("options") / "rec"
    record(path, seconds=1.5, velocities=True, gap=0.7)  # with velocities, and a 0.3 s dropout
    return path


def node_link_states(recording, parameters: dict) -> dict[int, cdr.MultiDofPoint]:
    """What the node publishes on link_states for the recording's joint states, by stamp."""
    pipeline = Pipeline(node_settings({"robot_description": PANDA.read_text(), **parameters}))
    store, out = typestore(), {}
    for _, raw in read_output(recording)["/joint_states"]:
        m = store.deserialize_cdr(raw, "sensor_msgs/msg/JointState")
        stamp = m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
        for result in pipeline.on_joint_state(stamp, m.name, m.position.tolist(), m.velocity.tolist()):
            link_states = dict(pipeline.encode(result))["~/link_states"]
            point = cdr.decode_multi_dof(link_states)
            out[point.stamp_ns] = point
    return out


def bag_link_states(recording, tmp_path, arguments: list[str]) -> dict[int, cdr.MultiDofPoint]:
    output = tmp_path / f"out{len(list(tmp_path.iterdir()))}"
    assert main(["bag", str(recording), "-o", str(output), "--urdf", str(PANDA), *arguments]) == 0
    points = [cdr.decode_multi_dof(raw) for _, raw in read_output(output)[LINK_STATES]]
    return {p.stamp_ns: p for p in points}


def as_rule(name: str, value) -> str:
    return f"{name}:={yaml.safe_dump(value, default_flow_style=True).strip().removesuffix('...').strip()}"


@pytest.mark.parametrize(("parameters", "streamed"), CASES, ids=[",".join(c[0]) for c in CASES])
def test_each_node_option_is_honoured_offline(recording, tmp_path, parameters, streamed) -> None:
    rules = [token for name, value in parameters.items() for token in ("-p", as_rule(name, value))]
    bag = bag_link_states(recording, tmp_path, rules)
    node = node_link_states(recording, parameters)
    default = node_link_states(recording, {})
    # the option changes the output (else this test would prove nothing)
    differs = set(node) != set(default) or any(
        node[s].joint_names != default[s].joint_names
        or node[s].frame_id != default[s].frame_id
        or not np.allclose(node[s].accelerations, default[s].accelerations, rtol=0, atol=1e-9)
        for s in node
    )
    assert differs
    # the bag writes what the node publishes: the same stamps (the whole-recording estimator may
    # differ at a stamp or two at a window's edge, where the node's jitter allowance decides) ...
    if streamed:
        assert set(bag) == set(node)
    else:
        assert len(set(bag) ^ set(node)) <= 4 and len(set(bag) & set(node)) > 300
    # ... the same frames and links, and the same numbers
    tolerance = 1e-9 if streamed else 1e-6
    for stamp in set(bag) & set(node):
        a, b = bag[stamp], node[stamp]
        assert a.frame_id == b.frame_id and a.joint_names == b.joint_names
        scale = max(1.0, float(np.abs(b.accelerations).max()))
        np.testing.assert_allclose(a.accelerations, b.accelerations, rtol=0, atol=tolerance * scale)
        np.testing.assert_allclose(a.velocities, b.velocities, rtol=0, atol=tolerance * scale)


def test_a_params_file_and_the_flags(recording, tmp_path) -> None:
    """--params takes the node's params file; flags override it and -p overrides both."""
    params = tmp_path / "params.yaml"
    params.write_text(
        yaml.safe_dump({"neforward": {"ros__parameters": {"estimator": {"mode": "causal"}, "frame_prefix": "file/"}}})
    )
    from_file = bag_link_states(recording, tmp_path, ["--params", str(params)])
    node = node_link_states(recording, {"estimator.mode": "causal", "frame_prefix": "file/"})
    assert set(from_file) == set(node) and all(p.frame_id == "file/panda_link0" for p in from_file.values())
    overridden = bag_link_states(
        recording, tmp_path, ["--params", str(params), "--mode", "fixed_lag", "-p", "frame_prefix:=cli/"]
    )
    assert all(p.frame_id == "cli/panda_link0" for p in overridden.values())
    assert set(overridden) != set(from_file)  # fixed lag again: its first estimate comes later
