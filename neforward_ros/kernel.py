"""The forward recursion's arithmetic, generated per model as straight-line Python.

:func:`kernel_source` writes the recursion of :mod:`neforward_ros.recursion` out for one model,
link by link and component by component, with the model's constants folded in: a joint axis along
z, an origin rotation of a quarter turn, a centre of mass at the link origin, the root at rest,
each make most products vanish, and what vanishes is never computed. The same code runs on Python
floats (one sample: no numpy call at all) and on numpy arrays of shape (T,) (T samples in one
vectorised pass), like the CDR encoders of :mod:`neforward_ros.wire.cdr`.

The generated function ``kernel(q, qd, qdd, root, sin, cos)`` takes the joint columns (sequences
indexed like ``model.joint_names``), the root's initial state ``root`` = (omega, alpha, v, a) as 12
values in the root frame, and returns one flat tuple: per link, in ``model.link_names`` order, the
``ROW`` numbers described by :data:`FIELDS`.
"""

from __future__ import annotations

import math
import re
import weakref
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from neforward_ros.model import JointKind, RobotModel

Value = float | str
"""A constant (folded at generation) or the name of a variable of the generated code."""

FIELDS = (
    ("omega", 3),  # angular velocity, link frame
    ("alpha", 3),  # angular acceleration, link frame
    ("velocity", 3),  # linear velocity of the origin, link frame
    ("accel", 3),  # specific force at the origin, link frame
    ("rotation", 9),  # link -> root, row-major
    ("position", 3),  # origin in the root frame
    ("com_accel", 3),  # specific force at the centre of mass, link frame
    ("com_velocity", 3),  # linear velocity of the centre of mass, link frame
    ("com_position", 3),  # centre of mass in the root frame
    ("orientation", 4),  # link -> root as a unit quaternion (x, y, z, w), either sign
)
"""The numbers of each link's row, in order."""

SLICES = {}
_start = 0
for _name, _width in FIELDS:
    SLICES[_name] = slice(_start, _start + _width)
    _start += _width
ROW = _start


@dataclass
class _Emitter:
    """Writes assignments, folding constants: a term with a zero factor is dropped, a unit factor is
    left out, constant terms are summed at generation."""

    lines: list[str]
    count: int = 0

    def temp(self, expression: str) -> str:
        self.count += 1
        name = f"t{self.count}"
        self.lines.append(f"    {name} = {expression}")
        return name

    def combine(self, terms: Sequence[tuple[Value, Value]], constant: float = 0.0) -> Value:
        """sum(a * b for a, b in terms) + constant, as a constant, an existing name or a new temporary."""
        parts: list[tuple[float, str]] = []  # (coefficient, product of names)
        for a, b in terms:
            coefficient = 1.0
            names = []
            for factor in (a, b):
                if isinstance(factor, str):
                    names.append(factor)
                else:
                    coefficient *= factor
            if coefficient == 0.0:
                continue
            if not names:
                constant += coefficient
                continue
            parts.append((coefficient, "*".join(names)))
        if not parts:
            return constant
        if len(parts) == 1 and parts[0][0] == 1.0 and constant == 0.0 and "*" not in parts[0][1]:
            return parts[0][1]
        text = ""
        for coefficient, names in parts:
            sign = "-" if coefficient < 0 else "+"
            magnitude = abs(coefficient)
            term = names if magnitude == 1.0 else f"{magnitude!r}*{names}"
            text = f"{'-' if sign == '-' else ''}{term}" if not text else f"{text} {sign} {term}"
        if constant != 0.0:
            text = f"{text} {'-' if constant < 0 else '+'} {abs(constant)!r}"
        return self.temp(text)

    def add(self, *values: Value) -> Value:
        return self.combine([(1.0, v) for v in values])

    def cross(self, a: Sequence[Value], b: Sequence[Value]) -> tuple[Value, ...]:
        return tuple(
            self.combine([(1.0, _mul(a[j], b[k])), (-1.0, _mul(a[k], b[j]))]) for j, k in ((1, 2), (2, 0), (0, 1))
        )


def _mul(a: Value, b: Value) -> Value:
    """A factor a * b: constants folded, names joined."""
    if not isinstance(a, str) and not isinstance(b, str):
        return a * b
    if not isinstance(a, str):
        return a if a == 0.0 else (b if a == 1.0 else f"{a!r}*{b}")
    if not isinstance(b, str):
        return b if b == 0.0 else (a if b == 1.0 else f"{b!r}*{a}")
    return f"{a}*{b}"


def _mat_vec(em: _Emitter, m: Sequence[Value], x: Sequence[Value], transpose: bool = False):
    """m @ x (or m.T @ x) for a row-major 3x3 m."""
    out = []
    for i in range(3):
        row = [(m[3 * k + i] if transpose else m[3 * i + k], x[k]) for k in range(3)]
        out.append(em.combine([(1.0, _mul(a, b)) for a, b in row]))
    return tuple(out)


def _mat_mat(em: _Emitter, a: Sequence[Value], b: Sequence[Value]) -> tuple[Value, ...]:
    return tuple(
        em.combine([(1.0, _mul(a[3 * i + k], b[3 * k + j])) for k in range(3)]) for i in range(3) for j in range(3)
    )


def kernel_source(model: RobotModel) -> str:
    """Python source of the model's kernel (see the module docstring)."""
    em = _Emitter(lines=[])
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
            state = _link(em, joint, parent)
            r_com = model.com_in_link[link]
        w, al, v, a = state["omega"], state["alpha"], state["velocity"], state["accel"]
        rc = tuple(float(x) for x in r_com)
        # a_c = a + alpha x r + omega x (omega x r); v_c = v + omega x r; c = p + R r
        w_x_r = em.cross(w, rc)
        state["com_velocity"] = tuple(em.add(v[i], w_x_r[i]) for i in range(3))
        al_x_r = em.cross(al, rc)
        w_x_wr = em.cross(w, w_x_r)
        state["com_accel"] = tuple(em.add(a[i], al_x_r[i], w_x_wr[i]) for i in range(3))
        com = _mat_vec(em, state["rotation"], rc)
        state["com_position"] = tuple(em.add(state["position"][i], com[i]) for i in range(3))
        states.append(state)
        for name, _ in FIELDS:
            outputs.extend(state[name])
    values = ", ".join(repr(float(v)) if not isinstance(v, str) else v for v in outputs)
    body = _inline_single_uses([*lines, f"    return ({values},)"])
    return "def kernel(q, qd, qdd, root, sin, cos):\n" + "\n".join(body) + "\n"


def _link(em: _Emitter, joint: Any, parent: dict[str, tuple[Value, ...]]) -> dict[str, tuple[Value, ...]]:
    """One link's state from its parent's, through its joint (the recursion of recursion.py)."""
    kind = joint.kind
    origin_rotation = tuple(float(x) for x in joint.origin_rotation)
    origin = tuple(float(x) for x in joint.origin_xyz)
    if kind is JointKind.FIXED:
        r: tuple[Value, ...] = origin_rotation
        p: tuple[Value, ...] = origin
        qd_j: Value = 0.0
        qdd_j: Value = 0.0
        q_joint: tuple[Value, ...] = _constant_quaternion(origin_rotation)
    else:
        k = joint.q_index
        m, offset = float(joint.multiplier), float(joint.offset)
        q_j = em.combine([(m, f"q{k}")], offset)
        qd_j = em.combine([(m, f"qd{k}")])
        qdd_j = em.combine([(m, f"qdd{k}")])
        if kind is JointKind.PRISMATIC:
            r = origin_rotation
            q_joint = _constant_quaternion(origin_rotation)
            d = joint.axis_in_parent
            p = tuple(em.combine([(float(d[i]), q_j)], origin[i]) for i in range(3))
        else:
            # Rodrigues: O Rot(e, q) = O + sin(q) O K + (1 - cos(q)) O K^2 = (O + OK^2) + sin(q) OK - cos(q) OK^2
            terms = joint.rotation_terms
            o, ok, okk = terms[0:9], terms[9:18], terms[18:27]
            # Half-angle sine and cosine give the quaternion, and sin q = 2 sh ch, cos q = 1 - 2 sh^2.
            half = em.combine([(0.5, q_j)])
            sh = em.temp(f"sin({half})") if isinstance(half, str) else math.sin(half)
            ch = em.temp(f"cos({half})") if isinstance(half, str) else math.cos(half)
            s = em.combine([(2.0, _mul(sh, ch))])
            c = em.combine([(-2.0, _mul(sh, sh))], 1.0)
            e = tuple(float(x) for x in joint.axis)
            q_joint = _quaternion_product(em, _constant_quaternion(o), e, sh, ch)
            r = tuple(
                em.combine([(float(ok[i]), s), (-float(okk[i]), c)], float(o[i]) + float(okk[i])) for i in range(9)
            )
            p = origin
    w_p, al_p, v_p, a_p = parent["omega"], parent["alpha"], parent["velocity"], parent["accel"]
    # In parent axes: c = omega_p x p, then v_p + c and a_p + alpha_p x p + omega_p x c.
    c = em.cross(w_p, p)
    v_par = tuple(em.add(v_p[i], c[i]) for i in range(3))
    al_x_p = em.cross(al_p, p)
    w_x_c = em.cross(w_p, c)
    a_par = tuple(em.add(a_p[i], al_x_p[i], w_x_c[i]) for i in range(3))
    # Into the child frame: x_child = r^T x_parent.
    w = _mat_vec(em, r, w_p, transpose=True)
    al = _mat_vec(em, r, al_p, transpose=True)
    v = _mat_vec(em, r, v_par, transpose=True)
    a = _mat_vec(em, r, a_par, transpose=True)
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
    rotation = _mat_mat(em, parent["rotation"], r)
    moved = _mat_vec(em, parent["rotation"], p)
    position = tuple(em.add(parent["position"][i], moved[i]) for i in range(3))
    orientation = _hamilton(em, parent["orientation"], q_joint)
    return {
        "omega": w,
        "alpha": al,
        "velocity": v,
        "accel": a,
        "rotation": rotation,
        "position": position,
        "orientation": orientation,
    }


def _constant_quaternion(matrix: Sequence[float]) -> tuple[float, ...]:
    """The unit quaternion (x, y, z, w) of a constant rotation matrix (row-major)."""
    from neforward_ros.rotations import quaternions

    return tuple(float(x) for x in quaternions([[list(matrix[0:3]), list(matrix[3:6]), list(matrix[6:9])]])[0])


def _hamilton(em: _Emitter, a: Sequence[Value], b: Sequence[Value]) -> tuple[Value, ...]:
    """a * b for quaternions (x, y, z, w): the rotation of a followed, in its frame, by b's."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (
        em.combine([(1.0, _mul(aw, bx)), (1.0, _mul(ax, bw)), (1.0, _mul(ay, bz)), (-1.0, _mul(az, by))]),
        em.combine([(1.0, _mul(aw, by)), (-1.0, _mul(ax, bz)), (1.0, _mul(ay, bw)), (1.0, _mul(az, bx))]),
        em.combine([(1.0, _mul(aw, bz)), (1.0, _mul(ax, by)), (-1.0, _mul(ay, bx)), (1.0, _mul(az, bw))]),
        em.combine([(1.0, _mul(aw, bw)), (-1.0, _mul(ax, bx)), (-1.0, _mul(ay, by)), (-1.0, _mul(az, bz))]),
    )


def _quaternion_product(
    em: _Emitter, origin: Sequence[float], axis: Sequence[float], sh: Value, ch: Value
) -> tuple[Value, ...]:
    """origin * (axis sin(q/2), cos(q/2)): a revolute joint's rotation as a quaternion."""
    turn = (_mul(axis[0], sh), _mul(axis[1], sh), _mul(axis[2], sh), ch)
    return _hamilton(em, origin, turn)


_TEMP = re.compile(r"\bt\d+\b")
_MAX_INLINED = 400  # characters: keeps expressions far from the parser's nesting limits


def _inline_single_uses(lines: list[str]) -> list[str]:
    """Substitute each temporary used exactly once into its use, and drop the unused ones: fewer
    stores and loads of locals, which is most of what straight-line Python spends its time on."""
    uses: dict[str, int] = {}
    for line in lines:
        right = line.split(" = ", 1)[1] if _TEMP.match(line.strip()) else line
        for name in _TEMP.findall(right):
            uses[name] = uses.get(name, 0) + 1
    pending: dict[str, str] = {}

    def substitute(match: re.Match) -> str:
        name = match.group(0)
        return f"({pending.pop(name)})" if name in pending else name

    out = []
    for line in lines:
        stripped = line.strip()
        if _TEMP.match(stripped) and " = " in stripped:
            name, expression = stripped.split(" = ", 1)
            expression = _TEMP.sub(substitute, expression)
            count = uses.get(name, 0)
            if count == 0:
                continue
            if count == 1 and len(expression) <= _MAX_INLINED:
                pending[name] = expression
                continue
            out.append(f"    {name} = {expression}")
        else:
            out.append(_TEMP.sub(substitute, line))
    return out


def compile_kernel(model: RobotModel) -> Callable[..., tuple[Any, ...]]:
    """The model's kernel as a Python function."""
    namespace: dict[str, Any] = {}
    exec(compile(kernel_source(model), f"<neforward kernel {model.name}>", "exec"), namespace)
    return namespace["kernel"]


_KERNELS: dict[int, Callable[..., tuple[Any, ...]]] = {}


def kernel_of(model: RobotModel) -> Callable[..., tuple[Any, ...]]:
    """The model's kernel, compiled on first use and kept as long as the model lives."""
    kernel = _KERNELS.get(id(model))
    if kernel is None:
        kernel = compile_kernel(model)
        _KERNELS[id(model)] = kernel
        weakref.finalize(model, _KERNELS.pop, id(model), None)
    return kernel
