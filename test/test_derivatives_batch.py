"""estimate_derivatives (whole recording) against the exact derivatives of a known signal."""

from __future__ import annotations

import numpy as np
import pytest

from neforward_ros import InputError
from neforward_ros.estimation.batch import estimate_derivatives

from conftest import EPOCH_NS, jittered_stamps, reference, relative_rms

INTERIOR = slice(100, -100)  # 0.2 s from either end


def test_polyfit_noise_free_accuracy() -> None:
    t = jittered_stamps(5000)
    q, qd_true, qdd_true = reference(t)
    qd, qdd = estimate_derivatives(t, q)
    assert relative_rms(qdd, qdd_true, INTERIOR) <= 2e-3
    assert relative_rms(qd, qd_true, INTERIOR) <= 1e-3


def test_polyfit_with_encoder_noise_and_the_baseline_it_beats() -> None:
    t = jittered_stamps(5000, seed=1)
    q, _, qdd_true = reference(t)
    noisy = q + np.random.default_rng(2).normal(0.0, 1e-4, len(q))
    _, qdd = estimate_derivatives(t, noisy)
    assert relative_rms(qdd, qdd_true, INTERIOR) <= 0.02
    # Plain differences amplify the same noise far beyond the signal.
    _, qdd_difference = estimate_derivatives(t, noisy, method="difference")
    assert relative_rms(qdd_difference, qdd_true, INTERIOR) > 1.0


def test_edges_are_one_sided_fits_not_nan() -> None:
    t = jittered_stamps(1000)
    q, qd_true, qdd_true = reference(t)
    qd, qdd = estimate_derivatives(t, q)
    assert np.all(np.isfinite(qd)) and np.all(np.isfinite(qdd))
    edges = np.r_[0:100, len(t) - 100 : len(t)]
    assert relative_rms(qdd[edges], qdd_true[edges]) <= 0.05
    assert relative_rms(qd[edges], qd_true[edges]) <= 5e-3


def test_several_columns_and_one_dimensional_input() -> None:
    t = jittered_stamps(800)
    columns = np.stack([reference(t, shift)[0] for shift in (0.0, 1.0, 2.0)], axis=1)
    qd, qdd = estimate_derivatives(t, columns)
    assert qd.shape == qdd.shape == (800, 3)
    qd1, qdd1 = estimate_derivatives(t, columns[:, 1])
    assert qd1.shape == (800,)
    np.testing.assert_allclose(qdd1, qdd[:, 1], rtol=0, atol=1e-9)


def test_epoch_sized_stamps_keep_their_precision() -> None:
    t = jittered_stamps(2000)
    q, _, qdd_true = reference(t)
    _, qdd_relative = estimate_derivatives(t, q)
    epoch_ns = np.int64(EPOCH_NS) + np.round(t * 1e9).astype(np.int64)
    _, qdd_ns = estimate_derivatives(epoch_ns, q)
    # only the rounding of t to whole ns differs: on noise-free samples it is the only noise there is,
    # and the noise read on the stamps sees it, so the windows chosen may differ; both are as close to
    # the truth (5.0e-6 and 5.3e-6)
    assert relative_rms(qdd_ns, qdd_relative) <= 3e-6
    assert relative_rms(qdd_ns, qdd_true, INTERIOR) <= 1e-5
    _, qdd_float = estimate_derivatives(1.7e9 + t, q)  # float epoch seconds: 0.24 us resolution
    assert relative_rms(qdd_float, qdd_true, INTERIOR) <= 2e-3


def test_continuous_joint_is_unwrapped() -> None:
    t = jittered_stamps(1500)
    angle = 3.0 + 2.5 * t + 0.3 * np.sin(4.0 * t)  # crosses +pi and keeps turning
    wrapped = np.angle(np.exp(1j * angle))
    qd, qdd = estimate_derivatives(t, np.stack([wrapped, wrapped], axis=1), wrap=[True, False])
    truth_qd = 2.5 + 1.2 * np.cos(4.0 * t)
    truth_qdd = -4.8 * np.sin(4.0 * t)
    assert np.max(np.abs(qd[:, 0] - truth_qd)) <= 1e-3
    assert np.max(np.abs(qdd[INTERIOR, 0] - truth_qdd[INTERIOR])) <= 1e-2
    assert np.max(np.abs(qd[:, 1])) > 100.0  # the wrapped column shows the jump it was not spared


def test_sparse_windows_widen_to_enough_samples() -> None:
    t = np.array([0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0])  # 2 Hz: no 0.2 s window holds 5 samples
    q = 0.5 * t**2 - t
    qd, qdd = estimate_derivatives(t, q)
    np.testing.assert_allclose(qd, t - 1.0, atol=1e-9)
    np.testing.assert_allclose(qdd, np.ones_like(t), atol=1e-9)


@pytest.mark.parametrize("t, q, kwargs, message", [
    ([0.0, 0.1, 0.1, 0.2], [0, 1, 2, 3], {}, "stamps must increase strictly: sample 2"),
    ([0.0, 0.2, 0.1, 0.3], [0, 1, 2, 3], {}, "split the recording"),
    ([0.0, 0.1, 0.2], [0, 1], {}, "q has shape"),
    ([0.0, 0.1], [0, 1], {}, "at least 3 samples"),
    ([0.0, 0.1, 0.2, 0.3], [0, np.nan, 2, 3], {}, "finite"),
    ([0.0, 0.1, 0.2, 0.3], [0, 1, 2, 3], {"method": "magic"}, "unknown method 'magic'"),
    ([0.0, 0.1, 0.2, 0.3], [0, 1, 2, 3], {"window": -1.0}, "window must be a positive"),
    ([0.0, 0.1, 0.2, 0.3], [0, 1, 2, 3], {"order": 1}, "order must be an integer of at least 2"),
    ([[0.0, 0.1, 0.2]], [0, 1, 2], {}, "stamps must be a 1-D array"),
    ([0.0, 0.1, 0.2, 0.3], [[0, 1]] * 4, {"wrap": [True]}, "wrap has 1 entries for 2 columns"),
])  # fmt: skip
def test_bad_input_raises_input_error(t, q, kwargs, message) -> None:
    with pytest.raises(InputError, match=message):
        estimate_derivatives(np.asarray(t), np.asarray(q), **kwargs)
