"""The backward (inverse-dynamics) recursion, generated per model as straight-line Python.

For each link i, leaves to root, in its own frame and about its own origin (the conventions of the
forward recursion: a_c is the specific force at the centre of mass, so gravity is already in it):

    F_i = m_i a_ci                                  N_i = I_ci alpha_i + omega_i x (I_ci omega_i)
    f_i = F_i + sum_c R_c f_c - f_ext,i
    n_i = N_i + r_ci x F_i + sum_c (R_c n_c + p_c x R_c f_c) - n_ext,i
    tau_i = n_i . z_i (revolute, continuous) or f_i . z_i (prismatic)

with c the children of i, R_c and p_c the rotation child -> parent and child origin of c's joint,
I_ci the inertia about the centre of mass along the link axes, (f_ext, n_ext) a wrench the
environment applies to link i (link frame, about its origin). f_i and n_i are the force and moment
link i receives from its parent through its parent joint; for the root, the wrench the world
applies to the base. A mimic joint's torque adds to its leader's column, times the multiplier.

Two functions per model, each in a variant with and without external wrenches:

- ``dynamics(q, qd, qdd, root, sin, cos, fext)``: the forward recursion (only the quantities the
  backward pass needs: omega, alpha, a_c) and the backward one in one straight-line function;
- ``backward(q, kin, sin, cos, fext)``: the backward pass alone, from the forward recursion's
  omega, alpha and a_c (``kin``: 9 values per link), the joint rotations recomputed from q.

Both return one flat tuple: per link f (3) and n (3), in link order, then the joint torques in
``model.joint_names`` order. Like the forward kernel they run on floats and on (T,) arrays.
"""

from __future__ import annotations

from neforward_ros.kinematics.codegen import Emitter, Kernel, PerModel, Value, finish, mat_vec
from neforward_ros.kinematics.forward_kernel import com_motion, joint_transform, link_state
from neforward_ros.model import JointKind, RobotModel

KIN_FIELDS = ("omega", "alpha", "com_accel")
"""What ``backward`` takes per link, 3 values each, in this order."""


def dynamics_source(model: RobotModel, *, from_kinematics: bool, external: bool) -> str:
    """Python source of ``backward`` (from_kinematics) or ``dynamics`` (see the module docstring)."""
    em = Emitter(lines=[])
    lines = em.lines
    n = len(model.joint_names)
    names = ("q",) if from_kinematics else ("q", "qd", "qdd")
    for name in names:
        for k in range(n):
            lines.append(f"    {name}{k} = {name}[{k}]")
    states: list[dict[str, tuple[Value, ...]]] = []
    if from_kinematics:
        for link in range(len(model.link_names)):
            state: dict[str, tuple[Value, ...]] = {}
            for f, field in enumerate(KIN_FIELDS):
                base = 9 * link + 3 * f
                state[field] = tuple(em.temp(f"kin[{base + c}]") for c in range(3))
            joint = model.parent_joints[link]
            if joint is not None:
                r, p, _, _, _ = joint_transform(em, joint, quaternion=False)
                state["joint_rotation"], state["joint_origin"] = r, p
            states.append(state)
    else:
        lines.append("    w0x, w0y, w0z, al0x, al0y, al0z, v0x, v0y, v0z, a0x, a0y, a0z = root")
        root = {
            "omega": ("w0x", "w0y", "w0z"),
            "alpha": ("al0x", "al0y", "al0z"),
            "velocity": ("v0x", "v0y", "v0z"),
            "accel": ("a0x", "a0y", "a0z"),
        }
        for link in range(len(model.link_names)):
            joint = model.parent_joints[link]
            state = dict(root) if joint is None else link_state(em, joint, states[joint.parent_index], poses=False)
            state.update(com_motion(em, state, tuple(float(x) for x in model.com_in_link[link])))
            states.append(state)
    outputs = _backward(em, model, states, external)
    values = ", ".join(repr(float(v)) if not isinstance(v, str) else v for v in outputs)
    body = finish([*lines, f"    return ({values},)"])
    header = (
        "def backward(q, kin, sin, cos, fext):"
        if from_kinematics
        else "def dynamics(q, qd, qdd, root, sin, cos, fext):"
    )
    return header + "\n" + "\n".join(body) + "\n"


def _backward(em: Emitter, model: RobotModel, states: list[dict], external: bool) -> list[Value]:
    count = len(model.link_names)
    # Sums over each link's children: R_c f_c and R_c n_c + p_c x R_c f_c, in the link's frame.
    child_force: list[list[tuple[Value, ...]]] = [[] for _ in range(count)]
    child_moment: list[list[tuple[Value, ...]]] = [[] for _ in range(count)]
    force: list[tuple[Value, ...]] = [()] * count
    moment: list[tuple[Value, ...]] = [()] * count
    torque: dict[int, list[tuple[float, Value]]] = {k: [] for k in range(len(model.joint_names))}
    for link in reversed(range(count)):
        state = states[link]
        mass = float(model.mass[link]) if model.mass else 0.0
        inertia = tuple(float(x) for x in model.inertia_in_link[link]) if model.inertia_in_link else (0.0,) * 9
        rc = tuple(float(x) for x in model.com_in_link[link])
        w, al, ac = state["omega"], state["alpha"], state["com_accel"]
        own_force = tuple(em.combine([(mass, ac[i])]) for i in range(3))
        iw = mat_vec(em, inertia, w)
        ial = mat_vec(em, inertia, al)
        w_x_iw = em.cross(w, iw)
        r_x_f = em.cross(rc, own_force)
        fext = [(-1.0, f"fext[{6 * link + i}]") for i in range(6)] if external else []
        f = tuple(
            em.combine([(1.0, own_force[i]), *((1.0, c[i]) for c in child_force[link]), *fext[i : i + 1]])
            for i in range(3)
        )
        n = tuple(
            em.combine(
                [
                    (1.0, ial[i]),
                    (1.0, w_x_iw[i]),
                    (1.0, r_x_f[i]),
                    *((1.0, c[i]) for c in child_moment[link]),
                    *fext[3 + i : 4 + i],
                ]
            )
            for i in range(3)
        )
        force[link], moment[link] = f, n
        joint = model.parent_joints[link]
        if joint is None:
            continue
        r, p = state["joint_rotation"], state["joint_origin"]
        rf = mat_vec(em, r, f)
        rn = mat_vec(em, r, n)
        p_x_rf = em.cross(p, rf)
        child_force[joint.parent_index].append(rf)
        child_moment[joint.parent_index].append(tuple(em.add(rn[i], p_x_rf[i]) for i in range(3)))
        if joint.kind is not JointKind.FIXED:
            axis = tuple(float(x) for x in joint.axis)
            along = f if joint.kind is JointKind.PRISMATIC else n
            torque[joint.q_index].append((float(joint.multiplier), em.combine([(axis[i], along[i]) for i in range(3)])))
    outputs: list[Value] = []
    for link in range(count):
        outputs.extend(force[link])
        outputs.extend(moment[link])
    outputs.extend(em.combine(torque[k]) for k in range(len(model.joint_names)))
    return outputs


def _compile(model: RobotModel, variant: tuple[bool, bool]) -> Kernel:
    from_kinematics, external = variant
    name = "backward" if from_kinematics else "dynamics"
    source = dynamics_source(model, from_kinematics=from_kinematics, external=external)
    return Kernel(source, name, f"{name} {model.name}")


_FUNCTIONS = PerModel(_compile)


def dynamics_of(model: RobotModel, *, external: bool = False) -> Kernel:
    """The model's ``dynamics`` function (forward and backward in one), compiled once."""
    return _FUNCTIONS(model, (False, external))


def backward_of(model: RobotModel, *, external: bool = False) -> Kernel:
    """The model's ``backward`` function (from the forward recursion's results), compiled once."""
    return _FUNCTIONS(model, (True, external))
