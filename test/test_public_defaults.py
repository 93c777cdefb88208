"""Every public function and class, called with its required arguments only: each documented default
works (``process_bag(input, output)`` once read ``options.settings`` before defaulting ``options``)."""

from __future__ import annotations

import inspect
from pathlib import Path

import numpy as np
import pytest

import neforward_ros
from neforward_ros import bag
from neforward_ros.bag import fleet

from conftest import CONFIG_DIR, require

PANDA = CONFIG_DIR / "panda.urdf"


def required(function) -> list[str]:
    """The parameters without a default (and not *args / **kwargs)."""
    kinds = (inspect.Parameter.POSITIONAL_ONLY, inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)
    return [
        p.name
        for p in inspect.signature(function).parameters.values()
        if p.kind in kinds and p.default is inspect.Parameter.empty
    ]


def call_with_required_only(function, values: dict):
    names = required(function)
    missing = [name for name in names if name not in values]
    assert not missing, f"{function.__qualname__}: the test has no value for {missing}"
    return function(**{name: values[name] for name in names})


def test_the_core_with_its_defaults() -> None:
    model = neforward_ros.load_model(PANDA)
    n = len(model.joint_names)
    t = np.arange(200) / 500.0
    values = {
        "source": PANDA,
        "model": model,
        "q": np.zeros(n),
        "qd": np.zeros(n),
        "qdd": np.zeros(n),
        "t": t,
        "joint_names": model.joint_names,
        "omega": np.zeros(3),
        "alpha": np.zeros(3),
        "velocity": np.zeros(3),
        "specific_force": np.array([0.0, 0.0, 9.81]),
    }
    values["q_batch"] = np.sin(t)[:, None] * np.ones(n)
    public = [getattr(neforward_ros, name) for name in neforward_ros.__all__]
    called = []
    for item in public:
        if not callable(item) or (isinstance(item, type) and issubclass(item, BaseException)):
            continue
        if inspect.isclass(item) and item.__name__ in (
            "RobotModel",
            "ParentJoint",
            "LinkKinematics",
            "InverseDynamics",
            "JointEstimate",
            "JointKind",
        ):
            continue  # results and parts of results, made by the library, not by callers
        arguments = dict(values)
        if getattr(item, "__name__", "") == "estimate_derivatives":
            arguments["q"] = values["q_batch"][:, 0]
        result = call_with_required_only(item, arguments)
        called.append(item.__name__)
        if isinstance(result, neforward_ros.StreamingEstimator):
            assert result.update(1, list(model.joint_names), [0.0] * n) == []
    assert {"load_model", "forward_recursion", "inverse_dynamics", "estimate_derivatives", "StreamingEstimator",
            "StreamSettings", "BaseMotion"} <= set(called)  # fmt: skip


def test_the_bag_tool_with_its_defaults(tmp_path: Path) -> None:
    require("rosbags")
    from test_bag import record

    record(tmp_path / "rec", seconds=1.0)  # with its robot_description
    report = call_with_required_only(bag.process_bag, {"input_path": tmp_path / "rec", "output_path": tmp_path / "out"})
    assert report.samples_out > 0 and (tmp_path / "out").is_dir()
    assert "joint states" in call_with_required_only(bag.describe, {"report": report})
    call_with_required_only(bag.BagOptions, {})
    call_with_required_only(bag.Progress, {})
    jobs = call_with_required_only(
        fleet.plan, {"inputs": call_with_required_only(fleet.recordings, {"inputs": [tmp_path / "rec"]}),
                     "output_dir": tmp_path / "fleet"})  # fmt: skip
    (tmp_path / "fleet").mkdir()
    outcome = call_with_required_only(fleet.run_job, {"job": jobs[0], "options": bag.BagOptions()})
    assert outcome.status == "done", outcome.message
    assert "1 done" in call_with_required_only(fleet.summary, {"outcomes": [outcome], "seconds": 1.0})


@pytest.mark.parametrize("name", sorted(neforward_ros.__all__))
def test_every_public_name_is_documented(name: str) -> None:
    item = getattr(neforward_ros, name)
    if callable(item):
        assert (item.__doc__ or "").strip(), f"{name} has no docstring"
