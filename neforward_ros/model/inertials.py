"""Links' inertial parameters other than the URDF's (identified by ``neforward calibrate``), put into a model."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from neforward_ros.errors import ModelError
from neforward_ros.model.types import RobotModel


def with_inertials(
    model: RobotModel,
    links: Sequence[str],
    masses: Sequence[float],
    coms: Sequence[Sequence[float]],
    inertias: Sequence[Sequence[float]],
) -> RobotModel:
    """The model with these links' mass (kg), centre of mass (m, link frame) and rotational inertia about
    it (kg m^2, link axes, as ``(ixx, ixy, ixz, iyy, iyz, izz)``) in place of the URDF's.

    Raises:
        ModelError: a link the model lacks, a count that does not match, a value that is not finite, a
            negative mass.
    """
    if not (len(links) == len(masses) == len(coms) == len(inertias)):
        raise ModelError("inertial parameters need one mass, centre of mass and inertia per link")
    count = len(model.link_names)
    mass = list(model.mass) if model.mass else [0.0] * count
    inertia = list(model.inertia_in_link) if model.inertia_in_link else [(0.0,) * 9] * count
    com = list(model.com_in_link)
    for link, m, c, i in zip(links, masses, coms, inertias, strict=True):
        if link not in model.link_index:
            raise ModelError(f"inertial parameters for link {link!r}, which robot {model.name!r} does not have")
        values = np.array([m, *c, *i], dtype=float)
        if len(c) != 3 or len(i) != 6 or not np.all(np.isfinite(values)) or m < 0.0:
            raise ModelError(f"link {link!r}: a mass >= 0 kg, a centre of mass (3) and an inertia (6), all finite")
        k = model.link_index[link]
        ixx, ixy, ixz, iyy, iyz, izz = (float(x) for x in i)
        mass[k] = float(m)
        com[k] = (float(c[0]), float(c[1]), float(c[2]))
        inertia[k] = (ixx, ixy, ixz, ixy, iyy, iyz, ixz, iyz, izz)
    warnings = tuple(w for w in model.inertia_warnings if not any(repr(link) in w for link in links))
    return replace(
        model, mass=tuple(mass), com_in_link=tuple(com), inertia_in_link=tuple(inertia), inertia_warnings=warnings
    )
