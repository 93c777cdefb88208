"""A payload the URDF does not have: a point mass on a link, merged into that link's inertia."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from neforward_ros.errors import ModelError
from neforward_ros.model.types import RobotModel


def with_payload(model: RobotModel, link: str, mass: float, com: Sequence[float]) -> RobotModel:
    """The model with a point mass of ``mass`` kg at ``com`` (m, in ``link``'s frame) rigidly on
    ``link``: the link's mass, centre of mass and inertia (about the new centre of mass, by the
    parallel-axis theorem) are those of the two together. ``mass`` 0 gives the model back.

    Raises:
        ModelError: ``link`` is not a link of the model, or the mass is negative or not finite.
    """
    if link not in model.link_index:
        raise ModelError(f"payload link {link!r} is not a link of robot {model.name!r}")
    if not (np.isfinite(mass) and mass >= 0.0) or len(com) != 3 or not np.all(np.isfinite(com)):
        raise ModelError(f"a payload needs a mass >= 0 kg and a finite centre of mass (x, y, z), got {mass}, {com}")
    if mass == 0.0:
        return model
    k = model.link_index[link]
    count = len(model.link_names)
    masses = list(model.mass) if model.mass else [0.0] * count
    inertias = list(model.inertia_in_link) if model.inertia_in_link else [(0.0,) * 9] * count
    coms = list(model.com_in_link)
    m0, c0 = masses[k], np.asarray(coms[k], dtype=float)
    cp = np.asarray(com, dtype=float)
    total = m0 + mass
    centre = (m0 * c0 + mass * cp) / total

    def shifted(m: float, offset: np.ndarray) -> np.ndarray:
        return m * (float(offset @ offset) * np.eye(3) - np.outer(offset, offset))

    inertia = np.asarray(inertias[k], dtype=float).reshape(3, 3) + shifted(m0, c0 - centre) + shifted(mass, cp - centre)
    masses[k] = float(total)
    coms[k] = tuple(float(x) for x in centre)
    inertias[k] = tuple(float(x) for x in inertia.reshape(9))
    return replace(model, mass=tuple(masses), com_in_link=tuple(coms), inertia_in_link=tuple(inertias))
