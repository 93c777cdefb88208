"""``neforward table``: each link's omega, alpha, accel and com_accel along the demo trajectory.

One batched call of :func:`neforward_ros.forward_recursion`; no DDS, no ROS.
"""

from __future__ import annotations

import numpy as np

from neforward_ros.demo.robot import demo_trajectory
from neforward_ros.model import load_model
from neforward_ros.recursion import DEFAULT_GRAVITY, forward_recursion
from neforward_ros.resources import DEFAULT_ROBOT, bundled_config_path


def _vector(values: np.ndarray) -> str:
    # round() then + 0.0 so that round-off such as -1e-16 prints as 0.000, not -0.000
    return "(" + ", ".join(f"{round(float(v), 3) + 0.0:8.3f}" for v in values) + ")"


def print_table(urdf: str | None, seconds: float, samples: int, root_link: str | None = None) -> None:
    path = urdf if urdf is not None else bundled_config_path(DEFAULT_ROBOT)
    model = load_model(path, root_link=root_link)
    times = np.linspace(0.0, seconds, samples)
    kin = forward_recursion(model, *demo_trajectory(model, times))
    gravity = ", ".join(f"{g:g}" for g in DEFAULT_GRAVITY)
    print(
        f"neforward demo: robot {model.name!r} from {path}\n"
        f"{len(model.link_names)} links, {len(model.joint_names)} joints, gravity ({gravity}) m/s^2 in the root "
        f"frame {model.root_link!r}.\nEvery vector is in its link's own frame; accel and com_accel are specific "
        "forces (what an accelerometer reads: +9.81 m/s^2 upward at rest)."
    )
    width = max(len(name) for name in model.link_names)
    header = (
        f"{'link':<{width}}  {'omega [rad/s]':^30}  {'alpha [rad/s^2]':^30}  "
        f"{'accel [m/s^2]':^30}  {'com_accel [m/s^2]':^30}"
    )
    for t, time in enumerate(times):
        print(f"\nt = {time:.3f} s")
        print(header)
        for k, name in enumerate(model.link_names):
            print(
                f"{name:<{width}}  {_vector(kin.omega[t, k])}  {_vector(kin.alpha[t, k])}  "
                f"{_vector(kin.accel[t, k])}  {_vector(kin.com_accel[t, k])}"
            )
