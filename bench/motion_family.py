"""The estimator benchmark's family of joint motions, with their exact accelerations.

- sums of four sines per joint, the fastest at 0.5, 1.5, 3 or 5 Hz (amplitudes 0.1-0.5 rad);
- minimum-jerk point-to-point moves (at most 3 rad/s and 20 rad/s^2) with dwells of 0.2-0.8 s;
- trapezoidal-velocity moves (acceleration limited: the acceleration jumps) with dwells;
- a legged gait's joint profile: a 1-2 Hz stride and its first five harmonics.

:func:`make` samples one at a rate, with +-5 % stamp jitter, through an encoder of some bits; with
``repeats``, that share of the samples repeats the previous sample's positions under its own stamp
(a driver that publishes before the encoder has a new reading).
"""

from __future__ import annotations

import numpy as np

EPOCH_NS = 1_700_000_000 * 10**9
"""ns: the benchmarks' stamps count from here (a date in 2023: an epoch, not zero, as drivers stamp)."""

KINDS = ("sines0.5", "sines1.5", "sines3", "sines5", "minjerk", "trapezoid", "gait")


def sines(t, fmax, rng, n=3):
    freqs = np.sort(rng.uniform(0.1, fmax, (n, 4)), axis=1)
    freqs[:, -1] = fmax
    amp = rng.uniform(0.1, 0.5, (n, 4))
    ph = rng.uniform(0, 2 * np.pi, (n, 4))
    w = 2 * np.pi * freqs
    arg = t[:, None, None] * w[None] + ph[None]
    return (amp * np.sin(arg)).sum(-1), (-amp * w**2 * np.sin(arg)).sum(-1)


def min_jerk(t, rng, n=3, vmax=3.0, amax=20.0, trapezoid=False):
    q = np.zeros((len(t), n))
    qdd = np.zeros((len(t), n))
    for j in range(n):
        pos, time = 0.0, 0.0
        while time < t[-1]:
            dwell = rng.uniform(0.2, 0.8)
            time += dwell
            dist = rng.uniform(0.2, 1.5) * rng.choice([-1, 1])
            if trapezoid:
                a = amax * 0.8
                v = min(vmax * 0.8, np.sqrt(abs(dist) * a))
                ta = v / a
                tc = max(abs(dist) / v - ta, 0.0)
                T = 2 * ta + tc
                m = (t >= time) & (t < time + T)
                s = t[m] - time
                acc = np.where(s < ta, a, np.where(s < ta + tc, 0.0, -a))
                disp = np.where(
                    s < ta,
                    0.5 * a * s**2,
                    np.where(s < ta + tc, 0.5 * a * ta**2 + v * (s - ta), abs(dist) - 0.5 * a * (T - s) ** 2),
                )
                q[m, j] = pos + np.sign(dist) * disp
                qdd[m, j] = np.sign(dist) * acc
            else:
                # min-jerk: peak v = 1.875 d/T, peak a = 5.77 d/T^2
                T = max(1.875 * abs(dist) / vmax, np.sqrt(5.77 * abs(dist) / amax))
                m = (t >= time) & (t < time + T)
                s = (t[m] - time) / T
                q[m, j] = pos + dist * (10 * s**3 - 15 * s**4 + 6 * s**5)
                qdd[m, j] = dist * (60 * s - 180 * s**2 + 120 * s**3) / T**2
            after = t >= time + T
            q[after, j] = pos + dist
            qdd[after, j] = 0.0
            pos += dist
            time += T
    return q, qdd


def gait(t, rng, n=3, f=None):
    f = f or rng.uniform(1.0, 2.0)
    h = np.arange(1, 6)
    q = np.zeros((len(t), n))
    qdd = np.zeros((len(t), n))
    for j in range(n):
        amp = rng.uniform(0.05, 0.4) / h**1.5
        ph = rng.uniform(0, 2 * np.pi, 5)
        w = 2 * np.pi * f * h
        arg = t[:, None] * w + ph
        q[:, j] = (amp * np.sin(arg)).sum(-1)
        qdd[:, j] = (-amp * w**2 * np.sin(arg)).sum(-1)
    return q, qdd


def make(kind: str, rate: float, bits: int, seed: int, seconds: float = 8.0, joints: int = 3, repeats: float = 0.0):
    """(t s, measured q, true q, true qdd), each (T, joints) but t (T,)."""
    rng = np.random.default_rng(seed)
    t = (np.arange(int(seconds * rate)) + rng.uniform(-0.05, 0.05, int(seconds * rate))) / rate
    if kind.startswith("sines"):
        q, qdd = sines(t, float(kind[5:]), rng, joints)
    elif kind == "minjerk":
        q, qdd = min_jerk(t, rng, joints)
    elif kind == "trapezoid":
        q, qdd = min_jerk(t, rng, joints, trapezoid=True)
    else:
        q, qdd = gait(t, rng, joints)
    step = 2 * np.pi / 2**bits
    measured = np.round(q / step) * step
    for k in np.flatnonzero(repeated(seed, len(t), repeats)):  # in order: a run holds the last new reading
        measured[k] = measured[k - 1]
    return t, measured, q, qdd


def bunched_times(seed: int, rate: float = 500.0, seconds: float = 3.0, period: float = 0.015) -> np.ndarray:
    """Stamps (s, whole nanoseconds) of a writer that stamps each message as it writes it and, on a
    loaded machine, runs only every ``period`` (+-30 %): it then writes every message due at ``rate``
    since, 40 us (+0-15 us) apart. Each position is taken at its own stamp (the writer of ``neforward
    demo``), so only the stamps' spacing differs from a steady stream's."""
    rng = np.random.default_rng(seed)
    out, now, written = [], 0.0, 0
    while now < seconds:
        now += period * rng.uniform(0.7, 1.3)
        due = int(now * rate)
        out += [now + k * 40e-6 + rng.uniform(0.0, 15e-6) for k in range(due - written)]
        written = max(written, due)
    return np.unique(np.round(np.array(out) * 1e9)) / 1e9


def repeated(seed: int, count: int, share: float) -> np.ndarray:
    """Which of :func:`make`'s ``count`` samples repeat the sample before (bool (count,))."""
    if not share:
        return np.zeros(count, dtype=bool)
    again = np.random.default_rng(seed + 1).random(count) < share
    again[0] = False
    return again
