"""``neforward table``: each link's omega, alpha, accel and com_accel along the demo trajectory.

One batched call of :func:`neforward_ros.forward_recursion`; no DDS, no ROS.
"""

from __future__ import annotations

import shutil
import textwrap

import numpy as np

from neforward_ros.demo.robot import demo_trajectory
from neforward_ros.kinematics.forward import DEFAULT_GRAVITY, forward_recursion
from neforward_ros.model import load_model
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
    columns = shutil.get_terminal_size((100, 40)).columns
    intro = (
        f"{len(model.link_names)} links, {len(model.joint_names)} joints, gravity ({gravity}) m/s^2 in the root "
        f"frame {model.root_link!r}. Every vector is in its link's own frame; accel and com_accel are specific "
        "forces (what an accelerometer reads: +9.81 m/s^2 upward at rest)."
    )
    print(f"neforward table: robot {model.name!r} from {path}")
    print(textwrap.fill(intro, width=min(columns, 100)))
    width = max(len(name) for name in model.link_names)
    quantities = [
        ("omega [rad/s]", kin.omega),
        ("alpha [rad/s^2]", kin.alpha),
        ("accel [m/s^2]", kin.accel),
        ("com_accel [m/s^2]", kin.com_accel),
    ]
    # Four vectors per line where the terminal is wide enough; else two blocks of two.
    per_line = 4 if width + 4 * 32 <= columns else 2
    blocks = [quantities[k : k + per_line] for k in range(0, 4, per_line)]
    for t, time in enumerate(times):
        print(f"\nt = {time:.3f} s")
        for block in blocks:
            print((f"{'link':<{width}}" + "".join(f"  {title:^30}" for title, _ in block)).rstrip())
            for k, name in enumerate(model.link_names):
                print(f"{name:<{width}}" + "".join(f"  {_vector(values[t, k])}" for _, values in block))
