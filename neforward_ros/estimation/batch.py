"""Joint velocities and accelerations of whole recordings (non-causal: the fit looks both ways).

:func:`estimate_derivatives` takes a recording of positions sampled at strictly increasing stamps;
:func:`estimate_at` evaluates the fit of each joint's own samples at any target times (joints
sampled by different drivers). Defaults (degree 4, 0.2 s window) were chosen for positions sampled
at a few hundred Hz with encoder-level noise; the README gives the measured accuracy.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from neforward_ros.errors import InputError
from neforward_ros.estimation import degree_choice, native_fit
from neforward_ros.estimation.adaptive import GAMMA, adaptive_fits, degree_fits
from neforward_ros.estimation.coverage import Support, covered_mask
from neforward_ros.estimation.fit import DEFAULT_WINDOW, check_settings, degrees, local_polynomial
from neforward_ros.stamps import NS, relative_seconds

CHOICE_BLOCK = 32768
"""Targets whose degrees the default's batch fit chooses at a time (:func:`chosen_degree_fits`)."""


def estimate_derivatives(
    t: Any,
    q: Any,
    *,
    method: str = "polyfit",
    window: float = DEFAULT_WINDOW,
    order: int | None = None,
    wrap: Sequence[bool] | None = None,
    adaptive: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """Velocities and accelerations of a whole recording of positions (non-causal).

    Args:
        t: sample stamps, shape (T,), strictly increasing: float seconds or integer nanoseconds.
        q: positions, shape (T,) or (T, n) (rad or m).
        method: ``"polyfit"`` (local polynomial fit, default) or ``"difference"``.
        window: full width in seconds of the local fit (polyfit). A window holding fewer than
            ``order + 1`` samples is widened to the ``order + 1`` nearest samples.
        order: degree of the local polynomial (polyfit), at least 2; None: for the adaptive fit, 6,
            4 or 2 per joint, chosen by the last second's estimates
            (:mod:`~neforward_ros.estimation.degree_choice`), as the node's default; 4 for the fixed
            window (:func:`~neforward_ros.estimation.fit.degrees`).
        wrap: per column, True for a continuous joint whose positions wrap at +-pi; those
            columns are unwrapped before differentiating.
        adaptive: polyfit: each column's window chosen per sample, up to ``window``, by the
            intersection-of-confidence-intervals rule (:mod:`neforward_ros.estimation.adaptive`),
            as the node's default; False: always ``window``.

    Returns:
        (qd, qdd), each with q's shape, in units per second and per second squared.

    Raises:
        InputError: stamps not strictly increasing, lengths that differ, NaN/inf, fewer than 3
            samples, or an unknown method or bad window/order.
    """
    seconds = relative_seconds(t)
    positions = np.asarray(q, dtype=float)
    one_dimensional = positions.ndim == 1
    if one_dimensional:
        positions = positions[:, None]
    if positions.ndim != 2 or positions.shape[0] != seconds.shape[0]:
        raise InputError(f"q has shape {np.shape(q)}; expected ({len(seconds)},) or ({len(seconds)}, n) to match t")
    order, lower = degrees(order, adaptive, causal=False)
    check_settings(method, window, order)
    if len(seconds) < 3:
        raise InputError(f"need at least 3 samples to estimate accelerations, got {len(seconds)}")
    if not np.all(np.isfinite(seconds)) or not np.all(np.isfinite(positions)):
        raise InputError("t and q must be finite (no NaN or inf)")
    steps = np.diff(seconds)
    if np.any(steps <= 0.0):
        k = int(np.argmax(steps <= 0.0))
        raise InputError(
            f"stamps must increase strictly: sample {k + 1} is not after sample {k}; "
            "split the recording where time goes backwards and estimate each segment on its own"
        )
    if wrap is not None:
        mask = np.asarray(wrap, dtype=bool)
        if mask.shape != (positions.shape[1],):
            raise InputError(f"wrap has {mask.size} entries for {positions.shape[1]} columns")
        positions = positions.copy()
        positions[:, mask] = np.unwrap(positions[:, mask], axis=0)

    if method == "difference":
        qd = np.gradient(positions, seconds, axis=0, edge_order=2)
        qdd = np.gradient(qd, seconds, axis=0, edge_order=2)
    elif adaptive and lower is not None:  # the estimates the node makes (their windows covered) are pooled
        support = Support(window / 2.0, window / 2.0, 2 * (lower + 1), window / (lower + 1))
        stamps_ns = np.round(seconds * NS).astype(np.int64)
        counted = covered_mask(seconds, seconds, support)[:, None]
        _, qd, qdd, _ = chosen_degree_fits(seconds, positions, seconds, window / 2.0, stamps_ns, counted)
    elif adaptive:
        _, qd, qdd, _ = adaptive_fits(seconds, positions, seconds, window / 2.0, order, window / 2.0)
    else:
        _, qd, qdd = local_polynomial(seconds, positions, seconds, window / 2.0, order)
    if one_dimensional:
        return qd[:, 0], qdd[:, 0]
    return qd, qdd


def estimate_at(
    t: np.ndarray,
    q: np.ndarray,
    targets: np.ndarray,
    *,
    velocity: np.ndarray | None = None,
    stamps_ns: np.ndarray | None = None,
    counted: np.ndarray | None = None,
    method: str = "polyfit",
    window: float = DEFAULT_WINDOW,
    order: int | None = None,
    adaptive: bool = True,
    spread: bool = False,
) -> tuple[np.ndarray, ...]:
    """Positions, velocities and accelerations at arbitrary target times, non-causal.

    The whole-recording estimate for joints sampled at their own times (partial messages from
    several drivers): columns of ``q`` share the sample times ``t``; ``targets`` need not be
    samples. Where a target is a sample, its position (and given velocity) is used as it is.

    Args:
        t: sample times (T,), s, strictly increasing, T >= 3.
        q: positions (T, m), already unwrapped.
        targets: times (M,), s.
        velocity: measured velocities (T, m), or None to differentiate positions; when given, the
            acceleration is the derivative of velocity.
        stamps_ns, counted: the default adaptive fit's degree choice (:func:`chosen_degree_fits`): the
            targets' stamps (M,), integer ns (None: the targets' seconds in ns), and which targets'
            estimates the node makes, (M,) or (M, m) (None: every one).
        method, window, order: as for :func:`estimate_derivatives`.
        adaptive: polyfit: each column's window chosen per target, up to ``window``, as the
            streaming estimator's (:mod:`neforward_ros.estimation.adaptive`).
        spread: also return the accelerations' standard deviations (NaN where the method gives none).

    Returns:
        three (M, m) arrays (four with ``spread``).
    """
    order, lower = degrees(order, adaptive, causal=False)
    check_settings(method, window, order)
    index = np.minimum(np.searchsorted(t, targets), len(t) - 1)
    exact = t[index] == targets
    std = np.full((len(targets), q.shape[1]), np.nan)
    if method == "difference":
        d1 = np.gradient(q, t, axis=0, edge_order=2) if velocity is None else velocity
        d2 = np.gradient(d1, t, axis=0, edge_order=2)
        columns = range(q.shape[1])
        q_at, qd_at, qdd_at = (np.stack([np.interp(targets, t, x[:, c]) for c in columns], axis=1) for x in (q, d1, d2))
    elif adaptive and lower is not None:
        if stamps_ns is None:
            stamps_ns = np.round(np.asarray(targets) * NS).astype(np.int64)
        if counted is None:
            counted = np.ones((len(targets), 1), dtype=bool)
        counted = counted if counted.ndim == 2 else counted[:, None]
        q_at, qd_at, qdd_at, std = chosen_degree_fits(t, q, targets, window / 2.0, stamps_ns, counted, velocity)
    elif adaptive:
        half_width = window / 2.0
        if velocity is None:
            q_at, qd_at, qdd_at, std = adaptive_fits(t, q, targets, half_width, order, half_width)
        else:  # the window chosen on the velocities, whose derivative is the acceleration
            q_at, _, _, _ = adaptive_fits(t, q, targets, half_width, order, half_width)
            qd_at, qdd_at, _, std = adaptive_fits(t, velocity, targets, half_width, order, half_width, derivative=1)
    else:
        half_width = window / 2.0
        q_at, qd_at, qdd_at = local_polynomial(t, q, targets, half_width, order)
        if velocity is not None:
            qd_at, qdd_at, _ = local_polynomial(t, velocity, targets, half_width, order)
    q_at[exact] = q[index[exact]]
    if velocity is not None:
        qd_at[exact] = velocity[index[exact]]
    return (q_at, qd_at, qdd_at, std) if spread else (q_at, qd_at, qdd_at)


def chosen_degree_fits(
    t: np.ndarray,
    q: np.ndarray,
    targets: np.ndarray,
    half_width: float,
    stamps_ns: np.ndarray,
    counted: np.ndarray,
    velocity: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The default adaptive fit at the targets: the rule run at every degree of
    :data:`~neforward_ros.estimation.degree_choice.DEGREES`, centred (half-width ``half_width``), and
    each joint's degree chosen per target by its estimates of the last second
    (:func:`~neforward_ros.estimation.degree_choice.choose`), the estimates at ``stamps_ns`` (M,)
    where ``counted`` (M, m or 1) pooled. Position, velocity, acceleration and its stated standard
    deviation (M, m); with ``velocity`` (T, m), the acceleration is the velocities' derivative and
    their fit's degree is the position's too.

    A block of :data:`CHOICE_BLOCK` targets at a time, each with the estimates of the second before
    its first (fitted again: a few percent more fits), which its first choices pool: every degree's
    estimates of a whole recording at once took several times the memory of its result (300,000
    targets of 8 joints: about 1 GB, which a virtual machine hands out at about 1.5 s a GB)."""
    m = q.shape[1]
    out = [np.empty((len(targets), m)) for _ in range(4)]
    counted = np.broadcast_to(counted, (len(targets), m))
    memory_ns = round(degree_choice.MEMORY * NS)
    for start in range(0, len(targets), CHOICE_BLOCK):
        stop = min(start + CHOICE_BLOCK, len(targets))
        first = int(np.searchsorted(stamps_ns, stamps_ns[start] - memory_ns, side="right"))
        part, kept = slice(first, stop), slice(start - first, None)
        got = _chosen_block(t, q, targets[part], half_width, stamps_ns[part], counted[part], velocity)
        for whole, block in zip(out, got, strict=True):
            whole[start:stop] = block[kept]
    return out[0], out[1], out[2], out[3]


def _chosen_block(
    t: np.ndarray,
    q: np.ndarray,
    targets: np.ndarray,
    half_width: float,
    stamps_ns: np.ndarray,
    counted: np.ndarray,
    velocity: np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`chosen_degree_fits` of one block of targets, with ``counted`` (M, m)."""
    degrees, finer = degree_choice.DEGREES, degree_choice.FINER
    options = degree_fits(t, q, targets, half_width, degrees, half_width, finer=finer)  # each (D, M, m)
    if velocity is not None:
        value, first, _, *deviations = degree_fits(t, velocity, targets, half_width, degrees, half_width, derivative=1,
                                                   finer=finer)  # fmt: skip
        options = (options[0], value, first, *deviations)
    library = native_fit.FIT.get()
    if library is not None:
        chosen, std = native_fit.choose_degrees(library, stamps_ns, round(degree_choice.MEMORY * NS), options[2],
                                                *options[3:], counted, degree_choice.LEAST, GAMMA,
                                                degree_choice.STRAIN, finer, degree_choice.WHITE,
                                                degree_choice.GROWTH, round(degree_choice.RECORD * NS),
                                                round(degree_choice.HOLE * NS))  # fmt: skip
    else:
        chosen, std = degree_choice.choose(stamps_ns, *(np.where(counted, option, np.nan) for option in options[2:]),
                                           finer=finer)  # fmt: skip
    q_at, qd_at, qdd_at = (degree_choice.pick(entries, chosen) for entries in options[:3])
    return q_at, qd_at, qdd_at, std
