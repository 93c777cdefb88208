"""What the node should have published for a moving robot, and the comparison with what arrived.

The expected values are ``forward_recursion`` at the true joint state of the client's analytic
trajectory (the recursion is checked against Pinocchio in test_recursion_pinocchio.py). The centre
of mass position and velocity come from the link's, by rigid-body kinematics written out here:
c = p + R r, v_c = R (v + omega x r).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from neforward_ros import forward_recursion, load_model
from neforward_ros.model import JointKind, RobotModel
from neforward_ros.stamps import NS

from conftest import EPOCH_NS


def moving_plan(model: RobotModel, **options) -> dict:
    """A plan for rclpy_client.py: every joint swings on its own sine (prismatic ones by 1 cm)."""
    amplitude, frequency, phase = [], [], []
    for k, name in enumerate(model.joint_names):
        joint = next(j for j in model.parent_joints if j is not None and j.name == name)
        amplitude.append(0.01 if joint.kind is JointKind.PRISMATIC else 0.5)
        frequency.append(0.3 + 0.1 * k)
        phase.append(0.4 * k)
    plan = {
        "names": list(model.joint_names),
        "amplitude": amplitude,
        "frequency": frequency,
        "phase": phase,
        "rate": 200.0,
        "count": 400,
        "epoch_ns": EPOCH_NS,
    }
    plan.update(options)
    return plan


def truth(model: RobotModel, plan: dict, t: np.ndarray):
    """q, qd, qdd of the plan's trajectory at times t (s since the epoch), shape (T, n)."""
    a, f, p = (np.asarray(plan[key]) for key in ("amplitude", "frequency", "phase"))
    w = 2 * math.pi * f
    arg = np.outer(t, w) + p
    return a * np.sin(arg), a * w * np.cos(arg), -a * w**2 * np.sin(arg)


def stamp_ns(message: dict) -> int:
    """The header stamp of a message (of its first marker for a MarkerArray)."""
    stamp = (message["markers"][0] if "markers" in message else message)["header"]["stamp"]
    return stamp["sec"] * NS + stamp["nanosec"]


def vec(d: dict) -> list[float]:
    return [d["x"], d["y"], d["z"]]


def rotation_matrix(q: dict) -> np.ndarray:
    x, y, z, w = q["x"], q["y"], q["z"], q["w"]
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def relative_error(actual: np.ndarray, expected: np.ndarray) -> float:
    """max |actual - expected| over max(1, max |expected|): relative to the field's scale."""
    actual, expected = np.asarray(actual, dtype=float), np.asarray(expected, dtype=float)
    assert actual.shape == expected.shape, (actual.shape, expected.shape)
    return float(np.max(np.abs(actual - expected)) / max(1.0, float(np.max(np.abs(expected)))))


class Expected:
    """The true kinematics at the stamps of the messages received."""

    def __init__(self, urdf: Path | str, plan: dict, gravity=(0.0, 0.0, -9.81)) -> None:
        self.model = load_model(urdf)  # a file, or the URDF text
        self.plan = plan
        self.gravity = gravity

    def at(self, stamps_ns: list[int], epoch_ns: int | None = None):
        epoch = self.plan["epoch_ns"] if epoch_ns is None else epoch_ns
        t = (np.asarray(stamps_ns, dtype=np.int64) - epoch) / NS
        kin = forward_recursion(self.model, *truth(self.model, self.plan, t), gravity=self.gravity)
        return kin, kin.in_root()

    def interior(self, messages: list[dict], margin_s: float = 0.25) -> list[dict]:
        """The messages whose stamps are at least margin_s from either end of the stream (the
        estimator's fit is one-sided there), so that accuracy is judged where it is promised."""
        first = self.plan["epoch_ns"]
        last = first + (self.plan["count"] - 1) * round(NS / self.plan["rate"])
        margin = round(margin_s * NS)
        return [m for m in messages if first + margin <= stamp_ns(m) <= last - margin]


def multi_dof_errors(messages: list[dict], expected: Expected, com: bool = False) -> dict[str, float]:
    """Relative errors of link_states (or com_states) against the truth at each message's stamp, for
    the links the messages name (all of them the same)."""
    model = expected.model
    stamps = [stamp_ns(m) for m in messages]
    kin, root = expected.at(stamps)
    com_in_link = np.asarray(model.com_in_link)
    got = {key: [] for key in ("translation", "rotation", "linear_velocity", "omega", "accel", "alpha")}
    names = messages[0]["joint_names"]
    rows = [model.link_index[name] for name in names]
    for message in messages:
        assert message["joint_names"] == names
        (point,) = message["points"]
        got["translation"].append([vec(t["translation"]) for t in point["transforms"]])
        got["rotation"].append([rotation_matrix(t["rotation"]) for t in point["transforms"]])
        got["linear_velocity"].append([vec(v["linear"]) for v in point["velocities"]])
        got["omega"].append([vec(v["angular"]) for v in point["velocities"]])
        got["accel"].append([vec(a["linear"]) for a in point["accelerations"]])
        got["alpha"].append([vec(a["angular"]) for a in point["accelerations"]])
    if com:
        position = root.position + np.einsum("tkij,kj->tki", root.rotation, com_in_link)
        velocity = np.einsum("tkij,tkj->tki", root.rotation, kin.velocity + np.cross(kin.omega, com_in_link))
        accel = root.com_accel
    else:
        position, velocity, accel = root.position, root.velocity, root.accel
    want = {
        "translation": position,
        "rotation": root.rotation,
        "linear_velocity": velocity,
        "omega": root.omega,
        "accel": accel,
        "alpha": root.alpha,
    }
    return {key: relative_error(np.array(got[key]), want[key][:, rows]) for key in want}


def per_link_errors(
    accel: list[dict], twist: list[dict], imu: list[dict], expected: Expected, link: str
) -> dict[str, float]:
    """AccelStamped, TwistStamped and Imu of one link (link frame) against the truth."""
    k = expected.model.link_index[link]
    out = {}
    kin, root = expected.at([stamp_ns(m) for m in accel])
    out["accel.linear"] = relative_error([vec(m["accel"]["linear"]) for m in accel], kin.accel[:, k])
    out["accel.angular"] = relative_error([vec(m["accel"]["angular"]) for m in accel], kin.alpha[:, k])
    kin, root = expected.at([stamp_ns(m) for m in twist])
    out["twist.linear"] = relative_error([vec(m["twist"]["linear"]) for m in twist], kin.velocity[:, k])
    out["twist.angular"] = relative_error([vec(m["twist"]["angular"]) for m in twist], kin.omega[:, k])
    kin, root = expected.at([stamp_ns(m) for m in imu])
    out["imu.linear_acceleration"] = relative_error([vec(m["linear_acceleration"]) for m in imu], kin.accel[:, k])
    out["imu.angular_velocity"] = relative_error([vec(m["angular_velocity"]) for m in imu], kin.omega[:, k])
    out["imu.orientation"] = relative_error([rotation_matrix(m["orientation"]) for m in imu], root.rotation[:, k])
    return out


def marker_errors(markers: list[dict], expected: Expected, scale: float) -> dict[str, float]:
    """Each ARROW runs from the link's centre of mass along its specific force, scale m per m/s^2."""
    model = expected.model
    stamps = [stamp_ns(m) for m in markers]
    _, root = expected.at(stamps)
    com = root.position + np.einsum("tkij,kj->tki", root.rotation, np.asarray(model.com_in_link))
    starts = [[vec(marker["points"][0]) for marker in m["markers"]] for m in markers]
    ends = [[vec(marker["points"][1]) for marker in m["markers"]] for m in markers]
    return {
        "start": relative_error(starts, com),
        "end": relative_error(ends, com + scale * root.com_accel),
    }
