"""neforward_ros: every link's angular velocity, angular acceleration and linear acceleration from
joint states and a URDF, by the Newton-Euler forward recursion."""

from neforward_ros.derivatives import JointEstimate, StreamingEstimator, StreamSettings, estimate_derivatives
from neforward_ros.errors import InputError, ModelError, NeforwardError
from neforward_ros.model import JointKind, ParentJoint, RobotModel, load_model
from neforward_ros.recursion import DEFAULT_GRAVITY, LinkKinematics, forward_recursion

__all__ = [
    "DEFAULT_GRAVITY",
    "InputError",
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
    "load_model",
]
