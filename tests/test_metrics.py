"""Tests of lagsplat.metrics (paper Section 4.1 "Metrics"; reference evaluation protocol)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter1d

from lagsplat import metrics as M
from lagsplat import timeseries as TS

DT = 1.0 / 30.0


def _sine(f_hz: float, n: int, dt: float = DT, phase: float = 0.4, amp: float = 1.0) -> np.ndarray:
    return amp * np.sin(2 * np.pi * f_hz * np.arange(n) * dt + phase)


# ----------------------------------------------------------------------------- frequency
@pytest.mark.parametrize("n", [128, 301, 600, 1024])
@pytest.mark.parametrize("cycles", [8.0, 9.37, 12.5, 17.21, 30.66])
@pytest.mark.parametrize("phase", [0.0, 1.1, 2.5])
def test_sinusoid_frequency_recovered(n: int, cycles: float, phase: float) -> None:
    f = cycles / (n * DT)  # non-integer bin positions included
    est = TS.spectral_peak_frequency(_sine(f, n, phase=phase), DT)
    assert abs(est - f) / f < 3e-3


def test_frequency_is_sub_bin() -> None:
    # The refinement must move off the bin grid (offset a quarter bin here).
    n = 512
    f = 20.25 / (n * DT)
    est = TS.spectral_peak_frequency(_sine(f, n), DT)
    assert abs(est - f) / f < 1e-3
    assert abs(est * n * DT - 20.0) > 0.1


def test_frequency_with_other_dt_and_offset() -> None:
    dt = 0.004
    n = 2000
    x = 7.0 + _sine(3.3, n, dt=dt)  # the mean is removed
    assert TS.spectral_peak_frequency(x, dt) == pytest.approx(3.3, rel=3e-3)


@pytest.mark.parametrize("seed", range(5))
def test_frequency_with_noise(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n, f = 450, 1.37
    x = _sine(f, n) + 0.3 * rng.standard_normal(n)
    assert abs(TS.spectral_peak_frequency(x, DT) - f) / f < 1e-2


@pytest.mark.parametrize("f_n", [0.7, 1.37, 2.2])
def test_damped_sinusoid(f_n: float) -> None:
    zeta = 0.05
    n = 450
    t = np.arange(n) * DT
    w0 = 2 * np.pi * f_n
    wd = w0 * np.sqrt(1 - zeta**2)
    x = np.exp(-zeta * w0 * t) * np.cos(wd * t)
    f_d = wd / (2 * np.pi)
    assert abs(TS.spectral_peak_frequency(x, DT) - f_d) / f_d < 1e-2


def test_g_aggregate_picks_the_mode_g_weighs_most() -> None:
    n = 600
    f1, f2 = 0.9, 2.3
    q = np.stack([_sine(f1, n, amp=1.0), _sine(f2, n, amp=1.0, phase=1.0)], axis=1)
    assert TS.spectral_peak_frequency(q, DT, G=np.diag([10.0, 0.1])) == pytest.approx(f1, rel=3e-3)
    assert TS.spectral_peak_frequency(q, DT, G=np.diag([0.1, 10.0])) == pytest.approx(f2, rel=3e-3)
    # In a mixed chart q' = q A^T the metric A^-T G A^-1 gives the same answer.
    A = np.array([[1.0, 0.8], [-0.5, 1.2]])
    Ai = np.linalg.inv(A)
    G = np.diag([0.1, 10.0])
    assert TS.spectral_peak_frequency(q @ A.T, DT, G=Ai.T @ G @ Ai) == pytest.approx(f2, rel=3e-3)
    # Without G the larger-amplitude mode wins.
    q2 = np.stack([_sine(f1, n, amp=0.3), _sine(f2, n, amp=1.0)], axis=1)
    assert TS.spectral_peak_frequency(q2, DT) == pytest.approx(f2, rel=3e-3)


def test_low_frequency_cut_ignores_drift() -> None:
    n = 400
    t = np.arange(n) * DT
    T = n * DT
    f = 10.5 / T
    osc = _sine(f, n)
    # A slow swing of one cycle per window, as strong as the oscillation: without
    # the cut it wins, with the default 1.5-cycle cut it is ignored.
    drift = np.sin(2 * np.pi * 1.0 / T * t + 0.3)
    assert TS.spectral_peak_frequency(osc + drift, DT, min_cycles=0.0) < 2.0 / T
    assert TS.spectral_peak_frequency(osc + drift, DT) == pytest.approx(f, rel=3e-3)
    # A linear drift spanning 15x the oscillation amplitude is ignored too.
    ramp = 15.0 * t / T
    assert TS.spectral_peak_frequency(osc + ramp, DT, min_cycles=0.0) < 2.0 / T
    assert TS.spectral_peak_frequency(osc + ramp, DT) == pytest.approx(f, rel=3e-3)


def test_frequency_errors() -> None:
    with pytest.raises(ValueError, match="flat"):
        TS.spectral_peak_frequency(np.full(100, 3.0), DT)
    with pytest.raises(ValueError, match="flat"):
        TS.spectral_peak_frequency(np.zeros((100, 2)), DT, G=np.eye(2))
    with pytest.raises(ValueError, match="8"):
        TS.spectral_peak_frequency(np.arange(7.0), DT)
    x = _sine(1.0, 100)
    x[10] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        TS.spectral_peak_frequency(x, DT)
    with pytest.raises(ValueError):
        TS.spectral_peak_frequency(np.zeros((10, 2, 2)), DT)
    with pytest.raises(ValueError, match="dt"):
        TS.spectral_peak_frequency(_sine(1.0, 100), 0.0)
    with pytest.raises(ValueError, match="G"):
        TS.spectral_peak_frequency(np.zeros((100, 2)) + _sine(1.0, 100)[:, None], DT, G=np.eye(3))


# ----------------------------------------------------------------------------- metric helpers
def test_top_direction_and_normalise_trace() -> None:
    rng = np.random.default_rng(0)
    Q, _ = np.linalg.qr(rng.standard_normal((4, 4)))
    evals = np.array([0.5, 3.0, 1.0, 0.1])
    G = Q @ np.diag(evals) @ Q.T
    u = M.top_direction(G)
    assert np.linalg.norm(u) == pytest.approx(1.0)
    assert u @ G @ u == pytest.approx(3.0)
    assert u[np.argmax(np.abs(u))] > 0
    np.testing.assert_allclose(M.top_direction(G), M.top_direction(G + 1e-12 * rng.standard_normal((4, 4))), atol=1e-6)
    Gn = M.normalise_trace(G)
    assert np.trace(Gn) == pytest.approx(4.0)
    np.testing.assert_allclose(Gn, Gn.T)
    assert np.trace(M.normalise_trace(G, d=2)) == pytest.approx(2.0)
    with pytest.raises(ValueError):
        M.normalise_trace(-np.eye(2))
    with pytest.raises(ValueError):
        M.top_direction(np.ones((2, 3)))


def test_project_and_spread() -> None:
    q = np.array([[1.0, 2.0], [3.0, 4.0], [5.0, 0.0]])
    np.testing.assert_allclose(M.project(q, [1.0, 0.0]), q[:, 0])
    with pytest.raises(ValueError):
        M.project(q, [1.0, 0.0, 0.0])
    G = np.diag([2.0, 0.5])
    dq = q - q.mean(0)
    expected = np.sqrt(np.mean(2.0 * dq[:, 0] ** 2 + 0.5 * dq[:, 1] ** 2))
    assert M.g_rms_spread(q, G) == pytest.approx(expected)
    with pytest.raises(ValueError):
        M.g_rms_spread(q, np.eye(3))


def _spd(rng: np.random.Generator, d: int) -> np.ndarray:
    A = rng.standard_normal((d, d))
    return A @ A.T + 0.1 * np.eye(d)


def test_nrmse_mean_and_perfect() -> None:
    rng = np.random.default_rng(1)
    d, N, H = 3, 7, 11
    G = _spd(rng, d)
    q_true = rng.standard_normal((N, H, d)) * [1.0, 2.0, 0.5] + [0.3, -1.0, 2.0]
    q_std = M.g_rms_spread(q_true.reshape(-1, d), G)
    mean_pred = np.broadcast_to(q_true.reshape(-1, d).mean(0), q_true.shape)
    assert M.latent_nrmse(mean_pred, q_true, G, q_std) == pytest.approx(1.0, abs=1e-12)
    assert M.latent_nrmse(q_true, q_true, G, q_std) == 0.0
    # Matches the reference's sqrt(mse_lat * d) / q_std.
    q_pred = q_true + 0.1 * rng.standard_normal(q_true.shape)
    delta = q_pred - q_true
    mse_lat = np.mean(np.einsum("nhi,ij,nhj->nh", delta, G, delta) / d)
    assert M.latent_nrmse(q_pred, q_true, G, q_std) == pytest.approx(np.sqrt(mse_lat * d) / q_std)


def test_nrmse_chart_invariance() -> None:
    rng = np.random.default_rng(2)
    d, N, H = 4, 5, 9
    G = _spd(rng, d)
    q_true = rng.standard_normal((N, H, d))
    q_pred = q_true + 0.3 * rng.standard_normal((N, H, d))
    P = rng.standard_normal((d, d)) + 2 * np.eye(d)
    assert abs(np.linalg.det(P)) > 1e-3
    Pi = np.linalg.inv(P)
    # Column-vector chart change q -> P q (rows: q @ P^T) with G -> P^-T G P^-1.
    G2 = Pi.T @ G @ Pi
    q_std = M.g_rms_spread(q_true.reshape(-1, d), G)
    q_std2 = M.g_rms_spread((q_true @ P.T).reshape(-1, d), G2)
    assert q_std2 == pytest.approx(q_std, rel=1e-10)
    a = M.latent_nrmse(q_pred, q_true, G, q_std)
    b = M.latent_nrmse(q_pred @ P.T, q_true @ P.T, G2, q_std2)
    assert b == pytest.approx(a, rel=1e-10)


def test_nrmse_errors() -> None:
    q = np.zeros((2, 3, 2))
    with pytest.raises(ValueError, match="shape"):
        M.latent_nrmse(q, np.zeros((2, 4, 2)), np.eye(2), 1.0)
    with pytest.raises(ValueError, match="q_std"):
        M.latent_nrmse(q, q, np.eye(2), 0.0)
    with pytest.raises(ValueError, match="G"):
        M.latent_nrmse(q, q, np.eye(3), 1.0)
    bad = q.copy()
    bad[0, 0, 0] = np.inf
    with pytest.raises(ValueError, match="non-finite"):
        M.latent_nrmse(bad, q, np.eye(2), 1.0)


def test_relative_error() -> None:
    assert M.relative_error(1.5016, 1.5621) == pytest.approx(0.0387299, rel=1e-5)
    assert M.relative_error(-2.0, -1.0) == pytest.approx(1.0)
    with pytest.raises(ValueError):
        M.relative_error(1.0, 0.0)
    with pytest.raises(ValueError):
        M.relative_error(float("nan"), 1.0)


def test_window_starts() -> None:
    a = M.window_starts(480, 1000)
    b = M.window_starts(480, 1000)
    np.testing.assert_array_equal(a, b)
    assert a.shape == (50,)
    assert a.min() >= 480 and a.max() < 1000
    np.testing.assert_array_equal(a, np.random.default_rng(0).integers(480, 1000, 50))
    c = M.window_starts(0, 3, n_windows=200, seed=5)
    assert set(c.tolist()) == {0, 1, 2}
    assert not np.array_equal(M.window_starts(0, 10**6, seed=1), M.window_starts(0, 10**6, seed=2))
    with pytest.raises(ValueError):
        M.window_starts(10, 10)


def test_image_mse() -> None:
    a = np.zeros((2, 4, 4, 3))
    b = np.full((2, 4, 4, 3), 0.5)
    assert M.image_mse(a, b) == pytest.approx(0.25)
    with pytest.raises(ValueError, match="shape"):
        M.image_mse(a, b[:1])
    with pytest.raises(ValueError, match="integer"):
        M.image_mse(a.astype(np.uint8), b)
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        M.image_mse(a, b * 4)


# ----------------------------------------------------------------------------- velocities / smoothing
def test_forward_difference_exact_on_quadratics() -> None:
    dt = 0.1
    t = np.arange(12) * dt
    q = np.stack([3 * t**2 - t + 2, -0.5 * t**2 + 4 * t], axis=1)
    v_true = np.stack([6 * t - 1, -t + 4], axis=1)
    v = TS.forward_difference_velocity(q, dt)
    assert v.shape == (10, 2)
    np.testing.assert_allclose(v, v_true[:-2], atol=1e-10)
    with pytest.raises(ValueError):
        TS.forward_difference_velocity(q[:2], dt)


def test_central_difference_and_offset() -> None:
    dt = 0.05
    t = np.arange(20) * dt
    q = np.stack([2 * t**2, np.sin(t)], axis=1)
    for k in (1, 3):
        v, off = TS.central_difference_velocity(q, dt, k=k)
        assert off == k
        assert v.shape == (20 - 2 * k, 2)
        np.testing.assert_allclose(v[:, 0], 4 * t[off : off + len(v)], atol=1e-10)
    with pytest.raises(ValueError):
        TS.central_difference_velocity(q[:4], dt, k=2)
    with pytest.raises(ValueError):
        TS.central_difference_velocity(q, dt, k=0)


def test_gaussian_smooth() -> None:
    rng = np.random.default_rng(3)
    q = rng.standard_normal((50, 3))
    s0 = TS.gaussian_smooth(q, 0)
    np.testing.assert_array_equal(s0, q)
    assert s0 is not q
    np.testing.assert_allclose(TS.gaussian_smooth(q, 1.0), gaussian_filter1d(q, 1.0, axis=0, mode="nearest"))
    const = np.ones((10, 2))
    np.testing.assert_allclose(TS.gaussian_smooth(const, 2.0), const)
    with pytest.raises(ValueError):
        TS.gaussian_smooth(q, -1.0)
