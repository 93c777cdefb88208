"""What a joint's measured effort means: the motor's torque, less friction and the rotor's inertia.

Per joint, in the model's column order, with qd the joint velocity (rad/s; m/s for a prismatic joint):

    motor torque     tau_m = scale * effort + offset                              (``effort.*``)
    friction         tau_f = (coulomb + stribeck * exp(-(qd / stribeck_velocity)^2)) * tanh(qd / velocity_scale)
                             + viscous * qd                                       (``friction.*``)
    rotor            tau_r = armature * qdd                                       (``effort.armature``)

The armature is the motor's rotor inertia seen at the joint (times the gear ratio squared, kg m^2;
kg for a prismatic joint), Pinocchio's ``model.armature``: the motor spends tau_r on spinning its
own rotor, which the URDF's links do not carry. It adds armature * qd to the joint's generalized
momentum, and armature to the mass matrix's diagonal.

The smooth sign tanh(qd / velocity_scale) turns friction on within about a velocity scale of rest
instead of at an exact zero no measured velocity ever has. The model torque behind external torques
is the inverse dynamics' plus tau_f and tau_r: external = tau_m - (inverse dynamics + tau_f + tau_r). The same
functions give the calibration's regressors (:mod:`neforward_ros.calibration`), so that what it fits
is what the node computes.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

DEFAULT_VELOCITY_SCALE = 0.01
"""rad/s (m/s): the smooth sign's scale when friction.velocity_scale does not give one."""
DEFAULT_STRIBECK_VELOCITY = 0.1
"""rad/s (m/s): the Stribeck term's velocity when friction.stribeck_velocity does not give one."""


@dataclass(frozen=True)
class EffortModel:
    """Per joint (n,) arrays in the model's column order; see the module docstring."""

    scale: np.ndarray
    offset: np.ndarray
    coulomb: np.ndarray
    viscous: np.ndarray
    velocity_scale: np.ndarray
    stribeck: np.ndarray
    stribeck_velocity: np.ndarray
    armature: np.ndarray | None = None  # None: 0 for every joint

    def __post_init__(self) -> None:
        if self.armature is None:
            object.__setattr__(self, "armature", np.zeros_like(np.asarray(self.scale, dtype=float)))

    @classmethod
    def of(
        cls,
        joint_names: Sequence[str],
        scale: Mapping[str, float] | None = None,
        offset: Mapping[str, float] | None = None,
        coulomb: Mapping[str, float] | None = None,
        viscous: Mapping[str, float] | None = None,
        velocity_scale: Mapping[str, float] | None = None,
        stribeck: Mapping[str, float] | None = None,
        stribeck_velocity: Mapping[str, float] | None = None,
        armature: Mapping[str, float] | None = None,
    ) -> EffortModel:
        """The model of these joints from per-joint values (joints not named: no friction, scale 1,
        offset 0, the default velocities, no armature)."""

        def column(values: Mapping[str, float] | None, default: float) -> np.ndarray:
            values = values or {}
            return np.array([float(values.get(name, default)) for name in joint_names])

        return cls(
            column(scale, 1.0),
            column(offset, 0.0),
            column(coulomb, 0.0),
            column(viscous, 0.0),
            column(velocity_scale, DEFAULT_VELOCITY_SCALE),
            column(stribeck, 0.0),
            column(stribeck_velocity, DEFAULT_STRIBECK_VELOCITY),
            column(armature, 0.0),
        )

    @property
    def has_friction(self) -> bool:
        return bool(np.any(self.coulomb) or np.any(self.viscous) or np.any(self.stribeck))

    def motor(self, efforts: np.ndarray) -> np.ndarray:
        """The motors' torques from measured efforts ((..., n); NaN stays NaN)."""
        return self.scale * efforts + self.offset

    def friction(self, qd: np.ndarray) -> np.ndarray:
        """Friction torques at joint velocities qd ((..., n))."""
        if not self.has_friction:
            return np.zeros_like(qd)
        sign, stribeck = friction_shapes(qd, self.velocity_scale, self.stribeck_velocity)
        return (self.coulomb + self.stribeck * stribeck) * sign + self.viscous * qd

    def rotor_torque(self, qdd: np.ndarray) -> np.ndarray:
        """The torques the motors spend on their rotors at joint accelerations qdd ((..., n)): armature * qdd."""
        return self.armature * qdd

    def rotor_momentum(self, qd: np.ndarray) -> np.ndarray:
        """The rotors' share of the generalized momentum at joint velocities qd ((..., n)): armature * qd."""
        return self.armature * qd

    def static_friction(self, qd: np.ndarray) -> np.ndarray:
        """The friction the model cannot sign at velocities qd ((..., n)): (coulomb + stribeck) times
        1 - |tanh(qd / velocity_scale)|, all of it at rest, none once the joint moves clearly."""
        if not self.has_friction:
            return np.zeros_like(qd)
        return (self.coulomb + self.stribeck) * (1.0 - np.abs(np.tanh(qd / self.velocity_scale)))

    def still(self, qd: np.ndarray) -> np.ndarray:
        """Whether every joint with a velocity in qd ((..., n)) is slower than its friction's velocity
        scale (static friction's regime): (...) bool."""
        return np.all(~(np.abs(qd) >= self.velocity_scale), axis=-1)


def friction_shapes(
    qd: np.ndarray, velocity_scale: np.ndarray | float, stribeck_velocity: np.ndarray | float
) -> tuple[np.ndarray, np.ndarray]:
    """(smooth sign tanh(qd / velocity_scale), Stribeck decay exp(-(qd / stribeck_velocity)^2)): the
    shapes the Coulomb and Stribeck coefficients multiply."""
    return np.tanh(qd / velocity_scale), np.exp(-np.square(qd / stribeck_velocity))
