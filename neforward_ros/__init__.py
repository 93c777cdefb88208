"""neforward_ros: every link's angular velocity, angular acceleration and linear acceleration from
joint states and a URDF, by the Newton-Euler forward recursion.

The public names below are imported on first use, so that importing a submodule (the command-line
entry points do) does not import numpy and the whole core first.
"""

from __future__ import annotations

import importlib

TYPE_CHECKING = False  # typing is not imported: the command line starts by importing this package

_EXPORTS = {
    "BaseMotion": "neforward_ros.kinematics.forward",
    "DEFAULT_GRAVITY": "neforward_ros.kinematics.forward",
    "InputError": "neforward_ros.errors",
    "InverseDynamics": "neforward_ros.kinematics.inverse_dynamics",
    "JointEstimate": "neforward_ros.estimation.estimate",
    "JointKind": "neforward_ros.model",
    "LinkKinematics": "neforward_ros.kinematics.forward",
    "ModelError": "neforward_ros.errors",
    "NeforwardError": "neforward_ros.errors",
    "ParentJoint": "neforward_ros.model",
    "RobotModel": "neforward_ros.model",
    "StreamSettings": "neforward_ros.estimation.settings",
    "StreamingEstimator": "neforward_ros.estimation.stream",
    "estimate_derivatives": "neforward_ros.estimation.batch",
    "forward_recursion": "neforward_ros.kinematics.forward",
    "inverse_dynamics": "neforward_ros.kinematics.inverse_dynamics",
    "load_model": "neforward_ros.model",
}

__all__ = [
    "DEFAULT_GRAVITY",
    "BaseMotion",
    "InputError",
    "InverseDynamics",
    "JointEstimate",
    "JointKind",
    "LinkKinematics",
    "ModelError",
    "NeforwardError",
    "ParentJoint",
    "RobotModel",
    "StreamSettings",
    "StreamingEstimator",
    "estimate_derivatives",
    "forward_recursion",
    "inverse_dynamics",
    "load_model",
]

if TYPE_CHECKING:
    from typing import Any

    from neforward_ros.errors import InputError, ModelError, NeforwardError
    from neforward_ros.estimation.batch import estimate_derivatives
    from neforward_ros.estimation.estimate import JointEstimate
    from neforward_ros.estimation.settings import StreamSettings
    from neforward_ros.estimation.stream import StreamingEstimator
    from neforward_ros.kinematics.forward import DEFAULT_GRAVITY, BaseMotion, LinkKinematics, forward_recursion
    from neforward_ros.kinematics.inverse_dynamics import InverseDynamics, inverse_dynamics
    from neforward_ros.model import JointKind, ParentJoint, RobotModel, load_model


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'neforward_ros' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *_EXPORTS])
