"""The compiled kernels give the Python kernels' numbers bit for bit (the same operations in the same
order, no contraction, the C library's sin and cos as Python's), for one sample and for a batch,
forward and backward, with and without external wrenches and a moving base, and the joint-space
terms (momentum, Coriolis, gravity, inertia matrix); without a compiler
(NEFORWARD_NATIVE=off) the Python kernels serve."""

from __future__ import annotations

import numpy as np
import pytest

from neforward_ros import BaseMotion, forward_recursion, inverse_dynamics, load_model
from neforward_ros.kinematics.backward_kernel import backward_of, dynamics_of
from neforward_ros.kinematics.forward_kernel import kernel_of
from neforward_ros.kinematics.joint_space import mass_matrix, momentum_terms
from neforward_ros.kinematics.joint_space_kernel import mass_matrix_of, momentum_of
from neforward_ros.kinematics.native import compiler

from conftest import TEST_ROBOTS

pytestmark = pytest.mark.skipif(compiler() is None, reason="no C compiler (cc): the Python kernels serve")


def outputs(model, q, qd, qdd, base, wrenches):
    kin = forward_recursion(model, q, qd, qdd, base=base)
    dyn = inverse_dynamics(model, q, qd, qdd, base=base, external_wrenches=wrenches)
    given = inverse_dynamics(model, q, qd, qdd, base=base, kinematics=kin, external_wrenches=wrenches)
    fields = ("omega", "alpha", "velocity", "accel", "com_accel", "com_velocity", "position", "rotation",
              "com_position", "orientation")  # fmt: skip
    terms = momentum_terms(model, q, qd)
    joint_space = [terms.momentum, terms.coriolis, terms.gravity, mass_matrix(model, q)]
    return [getattr(kin, f) for f in fields] + [dyn.joint_torque, dyn.wrench, given.joint_torque, given.wrench,
                                                *joint_space]  # fmt: skip


@pytest.mark.parametrize("robot", sorted(TEST_ROBOTS))
def test_compiled_kernels_give_the_python_kernels_numbers_bit_for_bit(robot: str, monkeypatch) -> None:
    model = load_model(TEST_ROBOTS[robot])
    n, links = len(model.joint_names), len(model.link_names)
    rng = np.random.default_rng(7)
    q, qd, qdd = (rng.uniform(-2.0, 2.0, (40, n)) for _ in range(3))
    base = BaseMotion(*(rng.normal(0.0, 1.0, (40, 3)) for _ in range(4)))
    wrenches = rng.normal(0.0, 5.0, (40, links, 6))
    cases = [
        (q, qd, qdd, None, None),
        (q, qd, qdd, base, wrenches),
        (q[3], qd[3], qdd[3], None, None),
        (q[5], qd[5], qdd[5], BaseMotion(*(x[5] for x in (base.omega, base.alpha, base.velocity, base.specific_force))),
         wrenches[5]),
    ]  # fmt: skip
    kernels = [kernel_of(model), dynamics_of(model), dynamics_of(model, external=True), backward_of(model),
               backward_of(model, external=True), momentum_of(model), mass_matrix_of(model)]  # fmt: skip
    monkeypatch.setenv("NEFORWARD_NATIVE", "off")  # the Python kernels first
    python = [outputs(model, *case) for case in cases]
    assert all(kernel.native.get() is None for kernel in kernels)
    monkeypatch.delenv("NEFORWARD_NATIVE")
    for kernel in kernels:
        kernel.native._failed = kernel.native._looked = False  # as in a process with a compiler
        assert kernel.native.get(wait=True) is not None
    for case, expected in zip(cases, python, strict=True):
        for got, want in zip(outputs(model, *case), expected, strict=True):
            np.testing.assert_array_equal(got, want)


def test_every_published_robots_kernel_translates_and_compiles(tmp_path, monkeypatch) -> None:
    """The translation handles whatever the generator writes: the corpus's largest robots."""
    import importlib.metadata
    from pathlib import Path

    from neforward_ros.kinematics.native import NativeKernel

    monkeypatch.setenv("NEFORWARD_CACHE", str(tmp_path))
    try:
        files = importlib.metadata.files("example-robot-data") or []
    except importlib.metadata.PackageNotFoundError:
        pytest.skip("pip install example-robot-data (a test extra)")
    paths = {Path(str(f.locate())).name: Path(str(f.locate())) for f in files if str(f).endswith(".urdf")}
    for name in ("talos_full_v2.urdf", "anymal-kinova.urdf"):
        model = load_model(paths[name], log=lambda *_: None)
        n = len(model.joint_names)
        q = np.random.default_rng(1).uniform(-1, 1, (3, n))
        monkeypatch.setenv("NEFORWARD_NATIVE", "off")
        expected = forward_recursion(model, q, q, q).accel
        monkeypatch.delenv("NEFORWARD_NATIVE")
        kernel = kernel_of(model)
        kernel.native = NativeKernel(kernel.source, "kernel")
        assert kernel.native.get(wait=True) is not None, name
        np.testing.assert_array_equal(forward_recursion(model, q, q, q).accel, expected)
