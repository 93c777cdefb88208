"""A streaming setting's q'' error against hindsight's on a motion of the estimator benchmark's family
(bench/motion_family.py), at seeds and rates the benchmark does not use: the tests' one measure."""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np

from neforward_ros.estimation.settings import StreamSettings
from neforward_ros.estimation.stream import StreamingEstimator

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
from hindsight import best, relative_rms
from motion_family import make, repeated

from conftest import EPOCH_NS


def setting_ratio(
    settings: StreamSettings,
    kind: str,
    rate: float,
    bits: int,
    seed: int,
    seconds: float = 3.0,
    prepare: Callable[[StreamingEstimator], None] | None = None,
    repeats: float = 0.0,
) -> float:
    """The setting's q'' relative RMS error over hindsight's for its delay (the best fixed-window
    polynomial whose window reaches at most that delay past the estimate, chosen knowing the truth),
    from 1 s to the last 0.5 s, every sample. ``prepare``: called with the estimator before the first
    message (a planted change). ``repeats``: that share of the samples repeats the last one's positions
    under its own stamp (a driver's repeats); those are left out of the error and of hindsight's fits."""
    t, q, _, qdd = make(kind, rate, bits, seed, seconds=seconds, repeats=repeats)
    names = [f"j{k}" for k in range(q.shape[1])]
    estimator = StreamingEstimator(names, settings=settings, log=lambda level, message: None)
    if prepare is not None:
        prepare(estimator)
    stamps = EPOCH_NS + np.round(t * 1e9).astype(np.int64)
    found: dict[int, np.ndarray] = {}
    for k in range(len(t)):
        for estimate in estimator.update(int(stamps[k]), names, q[k].tolist()):
            found[estimate.stamp_ns] = estimate.accelerations
    fresh = np.flatnonzero(~repeated(seed, len(t), repeats))
    evaluated = fresh[(t[fresh] > 1.0) & (t[fresh] < t[-1] - 0.5)]
    got = np.array([found[int(stamps[k])] for k in evaluated])
    reference = best(t[fresh], q[fresh], qdd[fresh], np.searchsorted(fresh, evaluated), settings.effective_lag)[0]
    return relative_rms(got, qdd[evaluated]) / reference
