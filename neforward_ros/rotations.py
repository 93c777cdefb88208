"""Rotations: quaternions of rotation matrices, and rotation matrices of quaternions.

Quaternions are (x, y, z, w), unit, with w >= 0, as geometry_msgs/Quaternion carries them.
"""

from __future__ import annotations

import math

import numpy as np


def quaternions(rotations: np.ndarray) -> np.ndarray:
    """Unit quaternions (x, y, z, w) with w >= 0 of rotation matrices, shape (..., 3, 3) -> (..., 4).

    Shepperd's method: of the four formulas, each row uses the one whose pivot (4 w^2, 4 x^2, 4 y^2
    or 4 z^2) is largest, which keeps full precision for every rotation. The tens of links of one
    sample go through a plain loop, several times faster there; batches are vectorised.
    """
    r = np.asarray(rotations, dtype=float)
    if r.size > 9 * 64:
        return _quaternions_vectorised(r)
    out = []
    for (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) in r.reshape(-1, 3, 3).tolist():
        trace = r00 + r11 + r22
        pivot = max(trace, r00, r11, r22)
        if pivot == trace:
            s = 2.0 * math.sqrt(max(1.0 + trace, 1e-300))
            q = ((r21 - r12) / s, (r02 - r20) / s, (r10 - r01) / s, 0.25 * s)
        elif pivot == r00:
            s = 2.0 * math.sqrt(max(1.0 + r00 - r11 - r22, 1e-300))
            q = (0.25 * s, (r01 + r10) / s, (r02 + r20) / s, (r21 - r12) / s)
        elif pivot == r11:
            s = 2.0 * math.sqrt(max(1.0 + r11 - r00 - r22, 1e-300))
            q = ((r01 + r10) / s, 0.25 * s, (r12 + r21) / s, (r02 - r20) / s)
        else:
            s = 2.0 * math.sqrt(max(1.0 + r22 - r00 - r11, 1e-300))
            q = ((r02 + r20) / s, (r12 + r21) / s, 0.25 * s, (r10 - r01) / s)
        norm = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
        sign = -1.0 if q[3] < 0.0 else 1.0
        out.append([sign * c / norm for c in q])
    return np.array(out).reshape(*r.shape[:-2], 4)


def _quaternions_vectorised(r: np.ndarray) -> np.ndarray:
    flat = r.reshape(-1, 3, 3)
    r00, r01, r02 = flat[:, 0, 0], flat[:, 0, 1], flat[:, 0, 2]
    r10, r11, r12 = flat[:, 1, 0], flat[:, 1, 1], flat[:, 1, 2]
    r20, r21, r22 = flat[:, 2, 0], flat[:, 2, 1], flat[:, 2, 2]
    trace = r00 + r11 + r22
    best = np.argmax(np.stack([trace, r00, r11, r22]), axis=0)
    pivot = np.choose(best, (1.0 + trace, 1.0 + 2 * r00 - trace, 1.0 + 2 * r11 - trace, 1.0 + 2 * r22 - trace))
    s = 2.0 * np.sqrt(np.maximum(pivot, 1e-300))
    inverse, quarter = 1.0 / s, 0.25 * s
    d21, d02, d10 = (r21 - r12) * inverse, (r02 - r20) * inverse, (r10 - r01) * inverse
    s21, s02, s10 = (r21 + r12) * inverse, (r02 + r20) * inverse, (r10 + r01) * inverse
    q = np.stack(
        [
            np.choose(best, (d21, quarter, s10, s02)),
            np.choose(best, (d02, s10, quarter, s21)),
            np.choose(best, (d10, s02, s21, quarter)),
            np.choose(best, (quarter, d21, d02, d10)),
        ],
        axis=1,
    )
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 3] < 0.0] *= -1.0
    return q.reshape(*r.shape[:-2], 4)


def rotation_matrix(quaternion: np.ndarray) -> np.ndarray:
    """The rotation matrices of unit quaternions (x, y, z, w), shape (..., 4) -> (..., 3, 3)."""
    x, y, z, w = np.moveaxis(np.asarray(quaternion, dtype=float), -1, 0)
    rows = (
        (1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)),
        (2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)),
        (2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)),
    )
    return np.stack([np.stack(row, axis=-1) for row in rows], axis=-2)
