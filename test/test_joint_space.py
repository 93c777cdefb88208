"""The joint-space terms the momentum observer needs, against Pinocchio: the inertia matrix (crba),
the momentum M qd, the Coriolis term C^T qd (computeCoriolisMatrix) and the gravity torques
(computeGeneralizedGravity), for one sample and a batch, on the test robots and every published
robot of example-robot-data that Pinocchio builds with the same joints.

Pinocchio's Coriolis matrix of a model with mimic joints does not satisfy dM/dt = C + C^T (its mimic
support leaves it out), so there C^T qd is checked against its definition instead: the gradient of
the kinetic energy 1/2 qd^T M(q) qd, by central differences of Pinocchio's own M."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from neforward_ros import ModelError, load_model
from neforward_ros.kinematics.joint_space import mass_matrix, momentum_terms

from conftest import TEST_ROBOTS
from oracle import PinocchioOracle
from test_corpus import example_robot_data

TOLERANCE = 1e-9


def pinocchio_terms(oracle: PinocchioOracle, names, q, qd) -> tuple[np.ndarray, ...]:
    """M, M qd, C^T qd, g in our joint columns."""
    qp, vp, _ = oracle.pin_vectors(names, q, qd, qd)
    model = oracle.model
    data = model.createData()  # Pinocchio's crba of a model with mimic joints adds to what a data held before
    inertia = pin.crba(model, data, qp)
    inertia = np.triu(inertia) + np.triu(inertia, 1).T
    coriolis = pin.computeCoriolisMatrix(model, data, qp, vp)
    gravity = pin.computeGeneralizedGravity(model, data, qp)
    columns = [iv for _, _, iv in oracle.joint_layout(names)]
    return (
        inertia[np.ix_(columns, columns)],
        (inertia @ vp)[columns],
        (coriolis.T @ vp)[columns],
        gravity[columns],
    )


def compare(path: Path, samples: int = 3) -> None:
    model = load_model(path)
    oracle = PinocchioOracle(path)
    names = model.joint_names
    rng = np.random.default_rng(len(names))
    q = rng.uniform(-1.5, 1.5, (samples, len(names)))
    qd = rng.uniform(-2.0, 2.0, (samples, len(names)))
    batch = momentum_terms(model, q, qd)
    inertia_batch = mass_matrix(model, q)
    for k in range(samples):
        inertia, momentum, coriolis, gravity = pinocchio_terms(oracle, names, q[k], qd[k])
        single = momentum_terms(model, q[k], qd[k])
        scale = 1.0 + np.abs(inertia).max() * (1.0 + np.abs(qd[k]).max() ** 2) + np.abs(gravity).max()
        for mine in (mass_matrix(model, q[k]), inertia_batch[k]):
            np.testing.assert_allclose(mine, inertia, rtol=0, atol=TOLERANCE * scale, err_msg=f"{path.name} M")
        for terms in (single, batch):
            got = [x if x.ndim == 1 else x[k] for x in (terms.momentum, terms.coriolis, terms.gravity)]
            for mine, want, what in zip(got, (momentum, coriolis, gravity), ("M qd", "C^T qd", "g"), strict=True):
                np.testing.assert_allclose(mine, want, rtol=0, atol=TOLERANCE * scale, err_msg=f"{path.name} {what}")


def has_mimic(path: Path) -> bool:
    return "<mimic" in path.read_text()


@pytest.mark.parametrize("robot", sorted(r for r in TEST_ROBOTS if not has_mimic(TEST_ROBOTS[r])))
def test_joint_space_terms_agree_with_pinocchio(robot: str) -> None:
    compare(TEST_ROBOTS[robot])


def test_joint_space_terms_agree_with_pinocchio_on_published_robots() -> None:
    files = [p for p in example_robot_data() if not has_mimic(p)]
    if not files:
        pytest.skip("pip install example-robot-data (a test extra)")
    checked = 0
    for path in files:
        try:
            model = load_model(path)
            oracle = PinocchioOracle(path)
        except (ModelError, ValueError, RuntimeError):
            continue  # a description either side refuses (the corpus test says which and why)
        if not model.joint_names or oracle.model.nv != len(model.joint_names):
            continue
        compare(path, samples=2)
        checked += 1
    assert checked >= 40, checked


@pytest.mark.parametrize("robot", sorted(r for r in TEST_ROBOTS if has_mimic(TEST_ROBOTS[r])))
def test_coriolis_term_of_mimic_models_is_the_kinetic_energy_gradient(robot: str) -> None:
    path = TEST_ROBOTS[robot]
    model = load_model(path)
    oracle = PinocchioOracle(path)
    names = model.joint_names
    rng = np.random.default_rng(3)
    q, qd = rng.uniform(-1.0, 1.0, len(names)), rng.uniform(-2.0, 2.0, len(names))
    step = 1e-6

    def energy(x: np.ndarray) -> float:
        return 0.5 * qd @ pinocchio_terms(oracle, names, x, qd)[0] @ qd

    gradient = np.array([(energy(q + step * e) - energy(q - step * e)) / (2 * step) for e in np.eye(len(names))])
    terms = momentum_terms(model, q, qd)
    np.testing.assert_allclose(terms.coriolis, gradient, rtol=0, atol=1e-6)
    inertia, momentum, _, gravity = pinocchio_terms(oracle, names, q, qd)
    np.testing.assert_allclose(mass_matrix(model, q), inertia, atol=1e-12)
    np.testing.assert_allclose(terms.momentum, momentum, atol=1e-12)
    np.testing.assert_allclose(terms.gravity, gravity, atol=1e-10)
