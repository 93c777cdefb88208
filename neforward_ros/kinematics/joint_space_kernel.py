"""Joint-space terms of the dynamics, generated per model as straight-line Python: the generalized
momentum and what its rate needs, and the joint-space inertia matrix.

With M(q) the joint-space inertia matrix, C(q, qd) the Coriolis matrix (any factorisation with
dM/dt = C + C^T, as Pinocchio's) and g(q) the gravity torques, the motors' torque tau, friction
tau_f and the environment's torque tau_ext satisfy, for the generalized momentum p = M(q) qd,

    dp/dt = tau - tau_f + tau_ext + C^T(q, qd) qd - g(q)

(no joint acceleration in it). Per joint i, with S_i its axis as a motion (revolute: angular z_i,
prismatic: linear z_i), v_i the spatial velocity of its child link and H_i the spatial momentum of
everything below the joint, all in the child link's frame and about its origin:

    p_i = S_i . H_i        (C^T qd)_i = H_i . (v_i x S_i)        g_i = S_i . W_i

with x the motion cross product and W_i the wrench that holds the subtree up against gravity: the
partial derivative of the kinetic energy with respect to q_i is (C^T qd)_i. The inertia matrix is
the composite-rigid-body algorithm's: M_ij = S_j . (I_i^c S_i) carried up from joint i to its
ancestor j, I_i^c the inertia of the subtree below joint i. A mimic joint's terms are added to its
leader's column, times the multiplier.

Two functions per model, each returning one flat tuple:

- ``momentum(q, qd, gravity_force, sin, cos)``: p (n), C^T qd (n), g (n), in ``model.joint_names``
  order; ``gravity_force``: the root's specific force at rest (minus gravity), in the root frame;
- ``mass_matrix(q, sin, cos)``: M row-major (n * n).

Like the other kernels they run on floats and on (T,) arrays (:mod:`.codegen`).
"""

from __future__ import annotations

from collections.abc import Sequence

from neforward_ros.kinematics.codegen import Emitter, Kernel, PerModel, Value, finish, mat_vec, mul
from neforward_ros.kinematics.forward_kernel import joint_transform
from neforward_ros.model import JointKind, RobotModel

Vector = tuple[Value, ...]


def _header_lines(em: Emitter, n: int, names: Sequence[str]) -> None:
    for name in names:
        for k in range(n):
            em.lines.append(f"    {name}{k} = {name}[{k}]")


def _inertia_about_origin(model: RobotModel, link: int) -> tuple[float, tuple[float, ...], tuple[float, ...]]:
    """(mass, first moment m c (3), rotational inertia about the link origin (9, row-major))."""
    mass = float(model.mass[link]) if model.mass else 0.0
    c = tuple(float(x) for x in model.com_in_link[link])
    inertia = tuple(float(x) for x in model.inertia_in_link[link]) if model.inertia_in_link else (0.0,) * 9
    cc = c[0] * c[0] + c[1] * c[1] + c[2] * c[2]
    about_origin = tuple(
        inertia[3 * i + j] + mass * ((cc if i == j else 0.0) - c[i] * c[j]) for i in range(3) for j in range(3)
    )
    return mass, tuple(mass * x for x in c), about_origin


def _dot(em: Emitter, a: Sequence[Value], b: Sequence[Value]) -> Value:
    return em.combine([(1.0, mul(a[i], b[i])) for i in range(3)])


def _to_parent(
    em: Emitter, r: Sequence[Value], p: Sequence[Value], force: Vector, moment: Vector
) -> tuple[Vector, Vector]:
    """A wrench (force, moment about the child origin) in the child frame, into the parent frame about
    the parent origin: R f, R n + p x R f."""
    rf = mat_vec(em, r, force)
    rn = mat_vec(em, r, moment)
    p_x_rf = em.cross(p, rf)
    return rf, tuple(em.add(rn[i], p_x_rf[i]) for i in range(3))


def momentum_source(model: RobotModel) -> str:
    """Python source of ``momentum`` (see the module docstring)."""
    em = Emitter(lines=[])
    n = len(model.joint_names)
    _header_lines(em, n, ("q", "qd"))
    em.lines.append("    gx, gy, gz = gravity_force")
    zero: Vector = (0.0, 0.0, 0.0)
    count = len(model.link_names)
    omega: list[Vector] = [zero] * count
    velocity: list[Vector] = [zero] * count
    specific: list[Vector] = [("gx", "gy", "gz")] * count
    transforms: list[tuple[Vector, Vector] | None] = [None] * count
    for link in range(count):
        joint = model.parent_joints[link]
        if joint is None:
            continue
        r, p, qd_j, _, _ = joint_transform(em, joint, quaternion=False)
        transforms[link] = (r, p)
        parent = joint.parent_index
        w_p, v_p = omega[parent], velocity[parent]
        c = em.cross(w_p, p)
        w = mat_vec(em, r, w_p, transpose=True)
        v = mat_vec(em, r, tuple(em.add(v_p[i], c[i]) for i in range(3)), transpose=True)
        specific[link] = mat_vec(em, r, specific[parent], transpose=True)
        if joint.kind is not JointKind.FIXED:
            e = tuple(float(x) for x in joint.axis)
            along = tuple(em.combine([(e[i], qd_j)]) for i in range(3))
            if joint.kind is JointKind.PRISMATIC:
                v = tuple(em.add(v[i], along[i]) for i in range(3))
            else:
                w = tuple(em.add(w[i], along[i]) for i in range(3))
        omega[link], velocity[link] = w, v
    # Leaves to root: the subtree's momentum (linear, angular about the origin) and gravity wrench.
    linear: list[list[Vector]] = [[] for _ in range(count)]
    angular: list[list[Vector]] = [[] for _ in range(count)]
    force: list[list[Vector]] = [[] for _ in range(count)]
    moment: list[list[Vector]] = [[] for _ in range(count)]
    terms: dict[str, list[list[tuple[float, Value]]]] = {k: [[] for _ in range(n)] for k in ("p", "c", "g")}
    for link in reversed(range(count)):
        mass, first, inertia = _inertia_about_origin(model, link)
        w, v = omega[link], velocity[link]
        w_x_h = em.cross(w, first)
        own_linear = tuple(em.combine([(mass, v[i]), (1.0, w_x_h[i])]) for i in range(3))
        h_x_v = em.cross(first, v)
        iw = mat_vec(em, inertia, w)
        own_angular = tuple(em.add(h_x_v[i], iw[i]) for i in range(3))
        own_force = tuple(em.combine([(mass, specific[link][i])]) for i in range(3))
        own_moment = em.cross(first, specific[link])
        total_l = tuple(em.add(own_linear[i], *(c[i] for c in linear[link])) for i in range(3))
        total_a = tuple(em.add(own_angular[i], *(c[i] for c in angular[link])) for i in range(3))
        total_f = tuple(em.add(own_force[i], *(c[i] for c in force[link])) for i in range(3))
        total_n = tuple(em.add(own_moment[i], *(c[i] for c in moment[link])) for i in range(3))
        joint = model.parent_joints[link]
        if joint is None:
            continue
        if joint.kind is not JointKind.FIXED:
            z = tuple(float(x) for x in joint.axis)
            multiplier = float(joint.multiplier)
            k = joint.q_index
            if joint.kind is JointKind.PRISMATIC:
                p_i = _dot(em, z, total_l)
                g_i = _dot(em, z, total_f)
                c_i = _dot(em, total_l, em.cross(w, z))
            else:
                p_i = _dot(em, z, total_a)
                g_i = _dot(em, z, total_n)
                c_i = em.add(_dot(em, total_a, em.cross(w, z)), _dot(em, total_l, em.cross(v, z)))
            for key, value in (("p", p_i), ("c", c_i), ("g", g_i)):
                terms[key][k].append((multiplier, value))
        transform = transforms[link]
        assert transform is not None
        r, p = transform
        parent = joint.parent_index
        moved_l, moved_a = _to_parent(em, r, p, total_l, total_a)
        moved_f, moved_n = _to_parent(em, r, p, total_f, total_n)
        linear[parent].append(moved_l)
        angular[parent].append(moved_a)
        force[parent].append(moved_f)
        moment[parent].append(moved_n)
    outputs = [em.combine(terms[key][k]) for key in ("p", "c", "g") for k in range(n)]
    values = ", ".join(repr(float(x)) if not isinstance(x, str) else x for x in outputs)
    body = finish([*em.lines, f"    return ({values},)"])
    return "def momentum(q, qd, gravity_force, sin, cos):\n" + "\n".join(body) + "\n"


def mass_matrix_source(model: RobotModel) -> str:
    """Python source of ``mass_matrix`` (see the module docstring)."""
    em = Emitter(lines=[])
    n = len(model.joint_names)
    _header_lines(em, n, ("q",))
    count = len(model.link_names)
    transforms: list[tuple[Vector, Vector] | None] = [None] * count
    children: list[list[int]] = [[] for _ in range(count)]
    for link in range(count):
        joint = model.parent_joints[link]
        if joint is not None:
            r, p, _, _, _ = joint_transform(em, joint, quaternion=False)
            transforms[link] = (r, p)
            children[joint.parent_index].append(link)
    # Composite inertias, leaves to root: mass, first moment, inertia about the origin (link frame).
    composite: list[tuple[float, Vector, Vector]] = [_inertia_about_origin(model, link) for link in range(count)]
    for link in reversed(range(count)):
        mass, first, inertia = composite[link]
        parts = [(mass, first, inertia)]
        for child in children[link]:
            transform = transforms[child]
            assert transform is not None
            parts.append(_shift_inertia(em, transform, *composite[child]))
        composite[link] = (
            sum(part[0] for part in parts),
            tuple(em.add(*(part[1][i] for part in parts)) for i in range(3)),
            tuple(em.add(*(part[2][i] for part in parts)) for i in range(9)),
        )
    entries: dict[tuple[int, int], list[tuple[float, Value]]] = {}
    for link in range(count):
        joint = model.parent_joints[link]
        if joint is None or joint.kind is JointKind.FIXED:
            continue
        mass, first, inertia = composite[link]
        z = tuple(float(x) for x in joint.axis)
        # The subtree's momentum for a unit rate of this joint: force f, moment about the origin.
        if joint.kind is JointKind.PRISMATIC:
            wrench: tuple[Vector, Vector] = (tuple(mass * z[i] for i in range(3)), em.cross(first, z))
        else:
            wrench = (em.cross(z, first), mat_vec(em, inertia, z))
        column, multiplier = joint.q_index, float(joint.multiplier)
        # Up the tree: each joint it passes (this one first) projects it on its own axis.
        at = link
        while True:
            upper = model.parent_joints[at]
            if upper is None:
                break
            if upper.kind is not JointKind.FIXED:
                axis = tuple(float(x) for x in upper.axis)
                value = _dot(em, axis, wrench[0] if upper.kind is JointKind.PRISMATIC else wrench[1])
                factor = float(upper.multiplier) * multiplier
                entries.setdefault((upper.q_index, column), []).append((factor, value))
                if at != link:  # an ancestor: the symmetric entry too
                    entries.setdefault((column, upper.q_index), []).append((factor, value))
            transform = transforms[at]
            assert transform is not None
            wrench = _to_parent(em, transform[0], transform[1], *wrench)
            at = upper.parent_index
    outputs = [em.combine(entries.get((i, j), [])) for i in range(n) for j in range(n)]
    values = ", ".join(repr(float(x)) if not isinstance(x, str) else x for x in outputs)
    body = finish([*em.lines, f"    return ({values},)"])
    return "def mass_matrix(q, sin, cos):\n" + "\n".join(body) + "\n"


def _shift_inertia(
    em: Emitter, transform: tuple[Vector, Vector], mass: float, first: Vector, inertia: Vector
) -> tuple[float, Vector, Vector]:
    """A child's (mass, first moment, inertia about its origin) in the parent's frame and about the
    parent's origin, the child's origin at p: h' = R h + m p and
    I' = R I R^T + m (|p|^2 1 - p p^T) + 2 (p . R h) 1 - p (R h)^T - (R h) p^T."""
    r, p = transform
    rh = mat_vec(em, r, first)
    columns = [mat_vec(em, r, tuple(inertia[3 * k + j] for k in range(3))) for j in range(3)]  # of R I
    rows = [mat_vec(em, r, tuple(columns[k][i] for k in range(3))) for i in range(3)]  # of R I R^T
    pp = _dot(em, p, p)
    p_rh = _dot(em, p, rh)
    shifted = []
    for i in range(3):
        for j in range(3):
            terms: list[tuple[Value, Value]] = [
                (1.0, rows[i][j]),
                (-mass, mul(p[i], p[j])),
                (-1.0, mul(p[i], rh[j])),
                (-1.0, mul(rh[i], p[j])),
            ]
            if i == j:
                terms += [(mass, pp), (2.0, p_rh)]
            shifted.append(em.combine(terms))
    moved = tuple(em.combine([(1.0, rh[i]), (mass, p[i])]) for i in range(3))
    return mass, moved, tuple(shifted)


def _compile(model: RobotModel, variant: str) -> Kernel:
    source = momentum_source(model) if variant == "momentum" else mass_matrix_source(model)
    return Kernel(source, variant, f"{variant} {model.name}")


_FUNCTIONS = PerModel(_compile)


def momentum_of(model: RobotModel) -> Kernel:
    """The model's ``momentum`` function, compiled once."""
    return _FUNCTIONS(model, "momentum")


def mass_matrix_of(model: RobotModel) -> Kernel:
    """The model's ``mass_matrix`` function, compiled once."""
    return _FUNCTIONS(model, "mass_matrix")
