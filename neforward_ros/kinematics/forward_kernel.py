"""The forward recursion's arithmetic, generated per model as straight-line Python.

:func:`kernel_source` writes the recursion of :mod:`neforward_ros.kinematics.forward` out for one model,
link by link and component by component, with the model's constants folded in: a joint axis along
z, an origin rotation of a quarter turn, a centre of mass at the link origin, the root at rest,
each make most products vanish, and what vanishes is never computed. The same code runs on Python
floats (one sample: no numpy call at all) and on numpy arrays of shape (T,) (T samples in one
vectorised pass), like the CDR encoders of :mod:`neforward_ros.wire.cdr`.

The generated function ``kernel(q, qd, qdd, root, sin, cos, copysign)`` takes the joint columns (sequences
indexed like ``model.joint_names``), the root's initial state ``root`` = (omega, alpha, v, a) as 12
values in the root frame, and returns one flat tuple: per link, in ``model.link_names`` order, the
``ROW`` numbers described by :data:`FIELDS`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from neforward_ros.kinematics.codegen import Emitter, Kernel, PerModel, Value, finish, mat_mat, mat_vec, mul
from neforward_ros.model import JointKind, RobotModel

FIELDS = (
    ("omega", 3),  # angular velocity, link frame
    ("alpha", 3),  # angular acceleration, link frame
    ("velocity", 3),  # linear velocity of the origin, link frame
    ("accel", 3),  # specific force at the origin, link frame
    ("rotation", 9),  # link -> root, row-major
    ("com_accel", 3),  # specific force at the centre of mass, link frame
    ("com_velocity", 3),  # linear velocity of the centre of mass, link frame
    ("position", 3),  # origin in the root frame
    ("orientation", 4),  # link -> root as a unit quaternion (x, y, z, w), w >= 0
    ("com_position", 3),  # centre of mass in the root frame
    ("com_orientation", 4),  # = orientation (so that each pose is 7 numbers in a row)
    # The link-frame vectors along the root axes (rotation @ vector), in the order of the MultiDOF
    # messages' twists and accelerations (linear, angular), the angular ones repeated for the centre
    # of mass: every block of link_states and com_states is a slice of the row.
    ("velocity_in_root", 3),
    ("omega_in_root", 3),
    ("accel_in_root", 3),
    ("alpha_in_root", 3),
    ("com_velocity_in_root", 3),
    ("com_omega_in_root", 3),  # = omega_in_root
    ("com_accel_in_root", 3),
    ("com_alpha_in_root", 3),  # = alpha_in_root
)
"""The numbers of each link's row, in order."""

IN_ROOT = ("velocity", "omega", "accel", "alpha", "com_velocity", "com_accel")
"""The link-frame vectors the row also gives along the root axes (``<name>_in_root``)."""

REPEATED = {
    "com_orientation": "orientation",
    "com_omega_in_root": "omega_in_root",
    "com_alpha_in_root": "alpha_in_root",
}
"""Numbers the row gives twice: field -> the field it repeats."""

SLICES = {}
_start = 0
for _name, _width in FIELDS:
    SLICES[_name] = slice(_start, _start + _width)
    _start += _width
ROW = _start


def kernel_source(model: RobotModel) -> str:
    """Python source of the model's kernel (see the module docstring)."""
    em = Emitter(lines=[])
    lines = em.lines
    n = len(model.joint_names)
    for name in ("q", "qd", "qdd"):
        for k in range(n):
            lines.append(f"    {name}{k} = {name}[{k}]")
    lines.append("    w0x, w0y, w0z, al0x, al0y, al0z, v0x, v0y, v0z, a0x, a0y, a0z = root")
    zero3 = (0.0, 0.0, 0.0)
    identity = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
    root = {
        "omega": ("w0x", "w0y", "w0z"),
        "alpha": ("al0x", "al0y", "al0z"),
        "velocity": ("v0x", "v0y", "v0z"),
        "accel": ("a0x", "a0y", "a0z"),
        "rotation": identity,
        "position": zero3,
        "orientation": (0.0, 0.0, 0.0, 1.0),
    }
    states: list[dict[str, tuple[Value, ...]]] = []
    outputs: list[Value] = []
    for link in range(len(model.link_names)):
        joint = model.parent_joints[link]
        if joint is None:
            state = dict(root)
            r_com = model.com_in_link[link]
        else:
            parent = states[joint.parent_index]
            state = link_state(em, joint, parent)
            r_com = model.com_in_link[link]
        rc = tuple(float(x) for x in r_com)
        state.update(com_motion(em, state, rc))
        com = mat_vec(em, state["rotation"], rc)
        state["com_position"] = tuple(em.add(state["position"][i], com[i]) for i in range(3))
        for name in IN_ROOT:
            state[f"{name}_in_root"] = mat_vec(em, state["rotation"], state[name])
        states.append(state)
        row = dict(state, orientation=_canonical(em, state["orientation"]))
        row.update({name: row[repeated] for name, repeated in REPEATED.items()})
        for name, _ in FIELDS:
            outputs.extend(row[name])
    values = ", ".join(repr(float(v)) if not isinstance(v, str) else v for v in outputs)
    body = finish([*lines, f"    return ({values},)"])
    return "def kernel(q, qd, qdd, root, sin, cos, copysign):\n" + "\n".join(body) + "\n"


def _canonical(em: Emitter, quaternion: Sequence[Value]) -> tuple[Value, ...]:
    """The quaternion with w >= 0 (the same rotation): multiplied by copysign(1, w)."""
    w = quaternion[3]
    if not isinstance(w, str):
        sign = -1.0 if math.copysign(1.0, w) < 0 else 1.0
        return tuple(em.combine([(sign, c)]) for c in quaternion)
    sign_name = em.temp(f"copysign(1.0, {w})")
    return tuple(em.combine([(1.0, mul(c, sign_name))]) for c in quaternion)


def joint_transform(
    em: Emitter, joint: Any, quaternion: bool = True
) -> tuple[tuple[Value, ...], tuple[Value, ...], Value, Value, tuple]:
    """A joint's rotation child -> parent (row-major) and child origin in the parent frame at its
    position, its rate and acceleration (scaled for a mimic joint), and its rotation as a quaternion
    (``quaternion=False``: not needed, () for a rotating joint, which then saves a few products)."""
    kind = joint.kind
    origin_rotation = tuple(float(x) for x in joint.origin_rotation)
    origin = tuple(float(x) for x in joint.origin_xyz)
    if kind is JointKind.FIXED:
        return origin_rotation, origin, 0.0, 0.0, _constant_quaternion(origin_rotation)
    k = joint.q_index
    m, offset = float(joint.multiplier), float(joint.offset)
    q_j = em.combine([(m, f"q{k}")], offset)
    qd_j = em.combine([(m, f"qd{k}")])
    qdd_j = em.combine([(m, f"qdd{k}")])
    if kind is JointKind.PRISMATIC:
        d = joint.axis_in_parent
        p = tuple(em.combine([(float(d[i]), q_j)], origin[i]) for i in range(3))
        return origin_rotation, p, qd_j, qdd_j, _constant_quaternion(origin_rotation)
    # Rodrigues: O Rot(e, q) = O + sin(q) O K + (1 - cos(q)) O K^2 = (O + OK^2) + sin(q) OK - cos(q) OK^2
    terms = joint.rotation_terms
    o, ok, okk = terms[0:9], terms[9:18], terms[18:27]
    if not quaternion:
        s = em.temp(f"sin({q_j})") if isinstance(q_j, str) else math.sin(q_j)
        c = em.temp(f"cos({q_j})") if isinstance(q_j, str) else math.cos(q_j)
        r = tuple(em.combine([(float(ok[i]), s), (-float(okk[i]), c)], float(o[i]) + float(okk[i])) for i in range(9))
        return r, origin, qd_j, qdd_j, ()
    # Half-angle sine and cosine give the quaternion, and sin q = 2 sh ch, cos q = 1 - 2 sh^2.
    half = em.combine([(0.5, q_j)])
    sh = em.temp(f"sin({half})") if isinstance(half, str) else math.sin(half)
    ch = em.temp(f"cos({half})") if isinstance(half, str) else math.cos(half)
    s = em.combine([(2.0, mul(sh, ch))])
    c = em.combine([(-2.0, mul(sh, sh))], 1.0)
    e = tuple(float(x) for x in joint.axis)
    q_joint = _quaternion_product(em, _constant_quaternion(o), e, sh, ch)
    r = tuple(em.combine([(float(ok[i]), s), (-float(okk[i]), c)], float(o[i]) + float(okk[i])) for i in range(9))
    return r, origin, qd_j, qdd_j, q_joint


def link_state(
    em: Emitter, joint: Any, parent: dict[str, tuple[Value, ...]], poses: bool = True
) -> dict[str, tuple[Value, ...]]:
    """One link's state from its parent's, through its joint (the recursion of recursion.py); also
    the joint's rotation child -> parent and child origin (``joint_rotation``, ``joint_origin``).
    ``poses=False``: motion only (no rotation to the root, position or orientation)."""
    kind = joint.kind
    r, p, qd_j, qdd_j, q_joint = joint_transform(em, joint, quaternion=poses)
    w_p, al_p, v_p, a_p = parent["omega"], parent["alpha"], parent["velocity"], parent["accel"]
    # In parent axes: c = omega_p x p, then v_p + c and a_p + alpha_p x p + omega_p x c.
    c = em.cross(w_p, p)
    v_par = tuple(em.add(v_p[i], c[i]) for i in range(3))
    al_x_p = em.cross(al_p, p)
    w_x_c = em.cross(w_p, c)
    a_par = tuple(em.add(a_p[i], al_x_p[i], w_x_c[i]) for i in range(3))
    # Into the child frame: x_child = r^T x_parent.
    w = mat_vec(em, r, w_p, transpose=True)
    al = mat_vec(em, r, al_p, transpose=True)
    v = mat_vec(em, r, v_par, transpose=True)
    a = mat_vec(em, r, a_par, transpose=True)
    if kind is not JointKind.FIXED:
        e = tuple(float(x) for x in joint.axis)
        j = tuple(em.combine([(e[i], qd_j)]) for i in range(3))  # qd e
        kk = tuple(em.combine([(e[i], qdd_j)]) for i in range(3))  # qdd e
        if kind is JointKind.PRISMATIC:
            v = tuple(em.add(v[i], j[i]) for i in range(3))
            w_x_j = em.cross(w, j)
            a = tuple(em.combine([(1.0, a[i]), (1.0, kk[i]), (2.0, w_x_j[i])]) for i in range(3))
        else:
            w = tuple(em.add(w[i], j[i]) for i in range(3))
            w_x_j = em.cross(w, j)
            al = tuple(em.add(al[i], kk[i], w_x_j[i]) for i in range(3))
    state = {"omega": w, "alpha": al, "velocity": v, "accel": a, "joint_rotation": r, "joint_origin": p}
    if poses:
        moved = mat_vec(em, parent["rotation"], p)
        state["rotation"] = mat_mat(em, parent["rotation"], r)
        state["position"] = tuple(em.add(parent["position"][i], moved[i]) for i in range(3))
        state["orientation"] = _hamilton(em, parent["orientation"], q_joint)
    return state


def com_motion(em: Emitter, state: dict[str, tuple[Value, ...]], rc: Sequence[float]) -> dict[str, tuple[Value, ...]]:
    """The centre of mass's velocity and specific force (link frame) from the link's state:
    v_c = v + omega x r, a_c = a + alpha x r + omega x (omega x r)."""
    w, al, v, a = state["omega"], state["alpha"], state["velocity"], state["accel"]
    w_x_r = em.cross(w, rc)
    al_x_r = em.cross(al, rc)
    w_x_wr = em.cross(w, w_x_r)
    return {
        "com_velocity": tuple(em.add(v[i], w_x_r[i]) for i in range(3)),
        "com_accel": tuple(em.add(a[i], al_x_r[i], w_x_wr[i]) for i in range(3)),
    }


def _constant_quaternion(matrix: Sequence[float]) -> tuple[float, ...]:
    """The unit quaternion (x, y, z, w) of a constant rotation matrix (row-major)."""
    from neforward_ros.rotations import quaternions

    return tuple(float(x) for x in quaternions([[list(matrix[0:3]), list(matrix[3:6]), list(matrix[6:9])]])[0])


def _hamilton(em: Emitter, a: Sequence[Value], b: Sequence[Value]) -> tuple[Value, ...]:
    """a * b for quaternions (x, y, z, w): the rotation of a followed, in its frame, by b's."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (
        em.combine([(1.0, mul(aw, bx)), (1.0, mul(ax, bw)), (1.0, mul(ay, bz)), (-1.0, mul(az, by))]),
        em.combine([(1.0, mul(aw, by)), (-1.0, mul(ax, bz)), (1.0, mul(ay, bw)), (1.0, mul(az, bx))]),
        em.combine([(1.0, mul(aw, bz)), (1.0, mul(ax, by)), (-1.0, mul(ay, bx)), (1.0, mul(az, bw))]),
        em.combine([(1.0, mul(aw, bw)), (-1.0, mul(ax, bx)), (-1.0, mul(ay, by)), (-1.0, mul(az, bz))]),
    )


def _quaternion_product(
    em: Emitter, origin: Sequence[float], axis: Sequence[float], sh: Value, ch: Value
) -> tuple[Value, ...]:
    """origin * (axis sin(q/2), cos(q/2)): a revolute joint's rotation as a quaternion."""
    turn = (mul(axis[0], sh), mul(axis[1], sh), mul(axis[2], sh), ch)
    return _hamilton(em, origin, turn)


def compile_kernel(model: RobotModel) -> Kernel:
    """The model's kernel (its Python function, and its compiled form when there is a compiler)."""
    return Kernel(kernel_source(model), "kernel", f"kernel {model.name}")


kernel_of = PerModel(compile_kernel)
"""``kernel_of(model)``: the model's kernel, compiled on first use and kept as long as the model lives."""
