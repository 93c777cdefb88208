"""Parameters: one table, and the params file, README and launch file agree with it."""

from __future__ import annotations

import ast
import re

import pytest

from neforward_ros import InputError
from neforward_ros.parameters.files import load_params_file, node_name_matches
from neforward_ros.parameters.qos_overrides import QosOverride
from neforward_ros.parameters.settings import node_settings
from neforward_ros.parameters.table import DEFAULTS, PARAMETERS

from conftest import CONFIG_DIR, TEST_DIR

ROOT = TEST_DIR.parent


def test_bundled_params_file_holds_every_default() -> None:
    values = load_params_file(CONFIG_DIR / "neforward.yaml")
    text = (CONFIG_DIR / "neforward.yaml").read_text()
    for name, default in DEFAULTS.items():
        if default == []:  # rcl's YAML parser cannot type an empty list: shown commented out
            assert re.search(rf"#\s*{re.escape(name)}:", text), name
        else:
            assert values[name] == default, name
    assert set(values) <= set(DEFAULTS)
    node_settings(values)


def test_readme_tables_every_parameter_with_type_default_and_whether_it_changes_at_run_time() -> None:
    readme = (ROOT / "README.md").read_text()
    for parameter in PARAMETERS:
        row = next((line for line in readme.splitlines() if line.startswith(f"| `{parameter.name}` |")), None)
        assert row is not None, f"README has no row for parameter {parameter.name}"
        assert f"| {parameter.type} |" in row, row
        assert ("| no |" if parameter.read_only else "| yes |") in row, row


def test_readme_tables_every_launch_argument() -> None:
    """The launch file runs for real in test/ros; here its arguments are checked against the README."""
    tree = ast.parse((ROOT / "launch" / "neforward.launch.py").read_text())
    declared = [
        node.args[0].value
        for node in ast.walk(tree)
        if isinstance(node, ast.Call) and getattr(node.func, "id", "") == "DeclareLaunchArgument"
    ]
    assert {"urdf", "namespace", "use_sim_time", "params_file"} <= set(declared), declared
    readme = (ROOT / "README.md").read_text()
    for name in declared:
        assert f"| `{name}` |" in readme, f"README does not table launch argument {name}"


def test_params_file_forms(tmp_path) -> None:
    path = tmp_path / "p.yaml"
    path.write_text(
        "/**:\n  ros__parameters:\n    max_gap: 1.0\n"
        "other_node:\n  ros__parameters:\n    max_gap: 9.0\n"
        "/robot1/neforward:\n  ros__parameters:\n    estimator:\n      window: 0.3\n    accel_links: [a, b]\n"
    )
    assert load_params_file(path) == {"max_gap": 1.0}  # /robot1/neforward is another node than /neforward
    values = load_params_file(path, namespace="/robot1")
    assert values == {"max_gap": 1.0, "estimator.window": 0.3, "accel_links": ["a", "b"]}
    settings = node_settings(values)
    assert settings.estimator.window == 0.3 and settings.accel_links == ("a", "b")


# What rcl (ROS 2 Jazzy) did with each params-file key for a node /robot1/neforward, tried with
# `ros2 run ... -r __ns:=/robot1 --params-file` and `ros2 param get`: the oracle for our matcher.
RCL_MATCHES = {
    "/**": True,
    "/*/neforward": True,
    "robot1/neforward": True,
    "/robot1/*": True,
    "/**/neforward": True,
    "/**/robot1/neforward": True,
    "neforward": False,
    "/neforward": False,
    "/*/*/neforward": False,
    "/robot2/neforward": False,
}


@pytest.mark.parametrize("key", sorted(RCL_MATCHES))
def test_params_file_keys_match_nodes_as_rcl_does(key: str) -> None:
    assert node_name_matches(key, "/robot1/neforward") is RCL_MATCHES[key]


def test_bundled_params_file_applies_in_any_namespace() -> None:
    for namespace in ("/", "/robot1", "/fleet/robot7"):
        assert load_params_file(CONFIG_DIR / "neforward.yaml", namespace=namespace)["max_gap"] == 0.5


@pytest.mark.parametrize(
    "values, text",
    [
        ({"max_gapp": 1.0}, "unknown parameter\\(s\\): max_gapp"),
        ({"max_gap": "1"}, "max_gap must be double"),
        ({"max_gap": 1}, "max_gap must be double, got the integer 1: .* write 1.0"),
        ({"gravity": [0, 0, -9.81]}, "gravity must be double, got the integer 0"),
        ({"qos_overrides./joint_states.subscription.reliability": "sometimes"}, "must be one of reliable"),
        ({"qos_overrides./joint_states.subscription.deadline": 1.0}, "not deadline"),
        ({"qos_overrides.joint_states.reliability": "reliable"}, "QoS overrides are named"),
        ({"use_sim_time": "yes"}, "use_sim_time must be bool"),
        ({"gravity": [0.0, -9.81]}, "gravity must have 3 components"),
        ({"velocity_source": "psychic"}, "velocity_source must be one of auto, message, differentiate"),
        ({"acceleration_source": "x"}, "acceleration_source must be one of estimate, supplied"),
        ({"estimator.mode": "instant"}, "estimator.mode must be one of"),
        ({"estimator.lag": 0.5}, "estimator parameters: lag must be between 0 and window"),
        ({"accel_links": "panda_hand"}, "accel_links must be string\\[\\]"),
        ({"qos_depth": 0}, "qos_depth must be at least 1"),
        ({"publish_markers": 1}, "publish_markers must be bool"),
        (
            {"external_torques.joint_names": ["a", "b"], "external_torques.dead_zones": [1.0]},
            "external_torques.joint_names and external_torques.dead_zones must have the same length",
        ),
        ({"external_torques.slow_gain": -1.0}, "slow_gain \\(1/s\\) and external_torques.dead_zones must be >= 0"),
    ],
)
def test_bad_values_name_the_parameter(values, text) -> None:
    with pytest.raises(InputError, match=text):
        node_settings(values)


def test_unreadable_params_file(tmp_path) -> None:
    with pytest.raises(InputError, match="cannot read params file"):
        load_params_file(tmp_path / "missing.yaml")
    (tmp_path / "list.yaml").write_text("- 1\n- 2\n")
    with pytest.raises(InputError, match="not a mapping"):
        load_params_file(tmp_path / "list.yaml")


def test_qos_overrides_and_ros_own_parameters_are_accepted() -> None:
    settings = node_settings(
        {
            "use_sim_time": True,
            "start_type_description_service": False,
            "qos_overrides./joint_states.subscription.reliability": "best_effort",
            "qos_overrides./joint_states.subscription.depth": 100,
            "qos_overrides./neforward/link_states.publisher.history": "keep_all",
        }
    )
    assert settings.qos_override("/joint_states", "subscription") == QosOverride(reliability="best_effort", depth=100)
    assert settings.qos_override("/neforward/link_states", "publisher") == QosOverride(history="keep_all")
    assert settings.qos_override("/joint_states", "publisher") == QosOverride()
