"""How honest the default's stated sigma is on the Panda's kind of data, where the truth is known.

``bench/bench_realdata.py`` measures the stated standard deviation of q'' against a reference, a
zero-phase 15 Hz low-pass of the recorded velocities differentiated on an even grid, which has errors
of its own. This bench makes recordings whose truth is known and which carry what the Panda's does:
its stamps, its repeated readings (the previous sample's positions and velocities under a new stamp,
at the same samples), and its velocity noise (per joint, the spread of the recorded velocity above
60 Hz, white). The true motion is the recorded velocity low-passed (zero-phase) at ``band`` Hz, a
cubic spline in time; its samples are taken either

- at the stamps (``stamps``: what the estimator assumes), or
- on the driver's 1 ms grid (``grid``: each stamp interval rounded to a whole number of milliseconds,
  at least one; the stamps then jitter about the sample times, as ``bench/bench_panda_noise.py``
  finds on the recording).

Per case it prints, per joint, the RMS of (q'' - truth) / sigma (1 for an honest sigma) for the
default setting (``StreamingEstimator``, the node's estimator, default parameters), the same against
the bench's reference computed from the synthetic samples, and the reference's own RMS error. Then,
on the recording itself, the RMS of (q'' - reference) / sigma against the bench's reference and
against the same low-pass on the samples re-timed to the 1 ms grid (the grid's missing slots
interpolated), whose time axis is the driver's.

Usage: python bench/bench_panda_sigma.py [--seeds 1 2]  (skips, saying why, without ../shared/realdata)
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from bench_realdata import CUTOFF_HZ, RECORDING, panda_urdf, read_joint_states, run_bag
from scipy.interpolate import CubicSpline
from scipy.signal import butter, filtfilt

from neforward_ros.estimation.settings import StreamSettings
from neforward_ros.estimation.stream import StreamingEstimator

GRID_S = 1e-3
"""The Panda driver's period, s."""
NOISE_ABOVE_HZ = 60.0
"""The recorded velocity's spread above this frequency is read as its white noise."""
BANDS = (6.0, 10.0)
"""Hz: the true motions' bands (the recording's velocity low-passed there)."""
SETTLE_S = 1.0
"""Estimates of the first second (the estimator's warm-up) are left out."""


def repeats(q: np.ndarray) -> np.ndarray:
    """Which samples repeat the previous one's positions exactly (n,)."""
    return np.r_[False, (np.diff(q, axis=0) == 0).all(axis=1)]


def grid_times(stamps: np.ndarray) -> np.ndarray:
    """Sample times on the driver's grid, s from the first: each stamp interval rounded to whole periods."""
    periods = np.maximum(np.round(np.diff(stamps) / (GRID_S * 1e9)), 1.0)
    return np.r_[0.0, np.cumsum(periods)] * GRID_S


def low_pass_on_grid(times: np.ndarray, v: np.ndarray, cutoff: float) -> tuple[np.ndarray, np.ndarray]:
    """(grid, v low-passed there): ``v`` at ``times`` (s) interpolated onto an even grid of GRID_S, then a
    4th-order Butterworth at ``cutoff`` Hz, forwards and backwards."""
    grid = np.arange(0.0, times[-1] + GRID_S / 2, GRID_S)
    b, a = butter(4, cutoff, fs=1.0 / GRID_S)
    on_grid = np.column_stack([np.interp(grid, times, v[:, j]) for j in range(v.shape[1])])
    return grid, filtfilt(b, a, on_grid, axis=0)


def velocity_noise(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Per joint, the spread of the recorded velocity above NOISE_ABOVE_HZ (repeated samples left out)."""
    b, a = butter(4, NOISE_ABOVE_HZ, fs=1.0 / GRID_S)
    residual = v - filtfilt(b, a, v, axis=0)
    return residual[~repeats(q)].std(axis=0)


def synthetic(stamps, q, v, band: float, timing: str, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(positions, velocities, true accelerations) at the recording's samples: see the module's text."""
    times = grid_times(stamps) if timing == "grid" else (stamps - stamps[0]) / 1e9
    grid, smooth = low_pass_on_grid(times, v, band)
    spline = CubicSpline(grid, smooth, axis=0)
    position = spline.antiderivative()
    q_true = q[0] + position(times) - position(times[0])
    rng = np.random.default_rng(seed)
    v_read = spline(times) + rng.normal(size=v.shape) * velocity_noise(q, v)
    q_read = q_true.copy()
    for k in np.flatnonzero(repeats(q)):  # the driver's repeats: the previous reading under a new stamp
        q_read[k], v_read[k] = q_read[k - 1], v_read[k - 1]
    return q_read, v_read, spline.derivative()(times)


def bench_reference(stamps: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``bench_realdata.reference``'s accelerations: the low-pass at CUTOFF_HZ over the samples as if evenly
    spaced at the median step, differentiated on that grid."""
    step = float(np.median(np.diff(stamps))) / 1e9
    b, a = butter(4, CUTOFF_HZ, fs=1.0 / step)
    return np.gradient(filtfilt(b, a, v, axis=0), step, axis=0)


def retimed_reference(stamps: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The same low-pass on the samples re-timed to the driver's grid, differentiated there, at the samples."""
    times = grid_times(stamps)
    grid, smooth = low_pass_on_grid(times, v, CUTOFF_HZ)
    acceleration = np.gradient(smooth, GRID_S, axis=0)
    return np.column_stack([np.interp(times, grid, acceleration[:, j]) for j in range(v.shape[1])])


def estimate(stamps: np.ndarray, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(sample rows, q'' estimates, stated sigmas) of the default setting fed every sample."""
    names = [f"j{k}" for k in range(q.shape[1])]
    estimator = StreamingEstimator(names, settings=StreamSettings())
    out: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for k in range(len(stamps)):
        for e in estimator.update(int(stamps[k]), names, q[k].tolist(), v[k].tolist()):
            out[e.stamp_ns] = (e.accelerations, e.acceleration_std)
    keys = np.array(sorted(out))
    return np.searchsorted(stamps, keys), np.array([out[s][0] for s in keys]), np.array([out[s][1] for s in keys])


def rms_z(estimates: np.ndarray, sigma: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Per joint, RMS((estimate - truth) / sigma) over the rows where all three are finite."""
    z = (estimates - truth) / sigma
    return np.sqrt(np.nanmean(z**2, axis=0))


def line(label: str, values: np.ndarray, digits: int = 2) -> str:
    return f"  {label:34s}" + " ".join(f"{x:6.{digits}f}" for x in values)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    args = parser.parse_args()
    if not RECORDING.is_dir():
        print(f"skipped: {RECORDING} is absent (the real recordings of ../shared/realdata)")
        return 0
    stamps, q, v, _ = read_joint_states(RECORDING)
    print(f"{RECORDING.name}: {len(stamps)} samples, {repeats(q).mean():.1%} repeated; velocity noise per joint",
          " ".join(f"{x:.4f}" for x in velocity_noise(q, v)), "rad/s")  # fmt: skip
    print("synthetic recordings (the recording's stamps, repeats and velocity noise; a known truth), default setting:")
    for band in BANDS:
        for timing in ("stamps", "grid"):
            for seed in args.seeds:
                q_read, v_read, truth = synthetic(stamps, q, v, band, timing, seed)
                rows, qdd, sigma = estimate(stamps, q_read, v_read)
                settled = (stamps[rows] - stamps[0]) / 1e9 >= SETTLE_S
                rows, qdd, sigma = rows[settled], qdd[settled], sigma[settled]
                reference = bench_reference(stamps, v_read)[rows]
                print(f" band {band:g} Hz, samples at the {timing}, seed {seed}:")
                print(line("RMS((q'' - truth) / sigma)", rms_z(qdd, sigma, truth[rows])))
                print(line("RMS((q'' - reference) / sigma)", rms_z(qdd, sigma, reference)))
                print(line("RMS error of q'', rad/s^2", np.sqrt(np.nanmean((qdd - truth[rows]) ** 2, axis=0)), 3))
                print(line("RMS error of the reference", np.sqrt(np.mean((reference - truth[rows]) ** 2, axis=0)), 3))
    print("the recording itself, default setting (neforward bag):")
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        out_stamps, _, qdd, sigma = run_bag(panda_urdf(), [], Path(tmp))
    rows = np.searchsorted(stamps, out_stamps)
    print(line("RMS((q'' - reference) / sigma)", rms_z(qdd, sigma, bench_reference(stamps, v)[rows])))
    print(line("the same, reference re-timed", rms_z(qdd, sigma, retimed_reference(stamps, v)[rows])))
    return 0


if __name__ == "__main__":
    sys.exit(main())
