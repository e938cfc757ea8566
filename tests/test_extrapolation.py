"""The extrapolation protocol of paper §4.3 (lagsplat.baselines.extrapolation), on exact oscillators."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from lagsplat.baselines import LatentNeuralODE, ode_rollout
from lagsplat.baselines.extrapolation import amplitude_left, decay_rate, extrapolation_metrics
from lagsplat.chart import Chart
from lagsplat.io.clip import HELD_OUT, TRAIN

DT = 1 / 30
F_HZ, ZETA = 0.8, 0.03


def _damped(q0: np.ndarray, v0: np.ndarray, dt: float, n: int, zeta: float = ZETA, f_hz: float = F_HZ) -> np.ndarray:
    """Exact free response of ``q'' + 2 zeta w q' + w^2 q = 0`` from ``(q0, v0)``: ``[n, 1]``."""
    w = 2 * math.pi * f_hz
    wd = w * math.sqrt(1 - zeta**2)
    t = np.arange(n) * dt
    a, b = float(q0[0]), (float(v0[0]) + zeta * w * float(q0[0])) / wd
    return (np.exp(-zeta * w * t) * (a * np.cos(wd * t) + b * np.sin(wd * t)))[:, None]


def _chart(seconds: float = 12.0) -> Chart:
    n = int(seconds / DT)
    q = _damped(np.array([1.0]), np.array([0.0]), DT, n)
    split = np.where(np.arange(n) < int(0.7 * n), TRAIN, HELD_OUT).astype(np.int8)
    I = np.eye(1)
    return Chart(mean=np.zeros(1), W=I, W_inv=I, q=q, t=np.arange(n) * DT, split=split, G_bar=I, A=I, ae_mse=np.zeros(n),
                 ae_floor_train=0.0, ae_floor_held_out=0.0, height=8, width=8)  # fmt: skip


def test_the_envelope_rate_and_the_amplitude_left_of_exact_signals() -> None:
    t = np.arange(3000) * DT
    w = 2 * math.pi * F_HZ
    p = 0.3 + np.exp(-0.2 * t) * np.cos(w * t)  # an offset rest does not matter
    assert decay_rate(p, DT, F_HZ) == pytest.approx(0.2, rel=0.02)
    assert amplitude_left(np.cos(w * t), DT, F_HZ) == pytest.approx(1.0, abs=0.01)  # a sustained orbit
    assert amplitude_left(p, DT, F_HZ) == pytest.approx(math.exp(-0.2 * (t[-1] - 1 / F_HZ)), rel=0.2)
    assert math.isnan(decay_rate(np.zeros(100), DT, F_HZ))


def test_a_dissipative_model_reaches_rest_and_an_undamped_one_keeps_orbiting() -> None:
    chart = _chart()
    exact = extrapolation_metrics(chart, lambda q0, v0, dt, n: _damped(q0, v0, dt, n), sigma=0.0)
    assert exact["freq_error"] < 0.02 and exact["dissipation_error"] < 0.05 and exact["amplitude_left"] < 1e-6
    assert exact["rate_real_per_s"] == pytest.approx(ZETA * 2 * math.pi * F_HZ, rel=0.05) and exact["psnr_mean"] is None
    orbit = extrapolation_metrics(chart, lambda q0, v0, dt, n: _damped(q0, v0, dt, n, zeta=0.0), sigma=0.0, long_s=200.0)
    assert orbit["freq_error"] < 0.02 and orbit["amplitude_left"] == pytest.approx(1.0, abs=0.02)
    assert orbit["dissipation_error"] == pytest.approx(1.0, abs=0.05)  # no decay at all: the whole coefficient is missing


def test_a_neural_ode_is_a_predictor() -> None:
    model = LatentNeuralODE(1, 0, hidden=())
    with torch.no_grad():
        w = 2 * math.pi * F_HZ
        model.net[0].weight.copy_(torch.tensor([[0.0, 1.0], [-w * w, -2 * ZETA * w]]))
        model.net[0].bias.zero_()

    def pred(q0, v0, dt, n):
        return ode_rollout(model, torch.tensor(q0[None], dtype=torch.float32), torch.tensor(v0[None], dtype=torch.float32), dt, n)[0].numpy()

    m = extrapolation_metrics(_chart(), pred, sigma=0.0, long_s=100.0)
    assert m["freq_error"] < 0.02 and m["dissipation_error"] < 0.05 and m["amplitude_left"] < 0.01


def test_a_chart_without_held_out_frames_is_refused() -> None:
    chart = _chart()
    chart.split[:] = TRAIN
    with pytest.raises(ValueError, match="no held-out segment"):
        extrapolation_metrics(chart, lambda q0, v0, dt, n: _damped(q0, v0, dt, n))


def test_the_figure_traces_follow_the_predictions_and_the_figure_is_drawn(tmp_path) -> None:
    from lagsplat.baselines.extrapolation import protocol_windows, real_trace
    from lagsplat.viz.extrapolation import extrapolation_figure

    chart = _chart()
    orbit = lambda q0, v0, dt, n: _damped(q0, v0, dt, n, zeta=0.0)  # noqa: E731
    m = extrapolation_metrics(chart, orbit, sigma=0.0, long_s=200.0, figure_s=20.0)
    w = protocol_windows(chart, 200.0, 0.0, 20.0)
    near, far = np.array(m["trace"]["near"]), np.array(m["trace"]["far"])
    assert len(near) == w.n_near == round(20.0 / DT) + 1 and len(far) == w.m_period
    q0 = chart.q[w.ho[0], 0]
    assert near[0] == pytest.approx(q0, abs=1e-6) and np.ptp(far) == pytest.approx(np.ptp(near[: w.m_period]), rel=0.02)  # still orbiting
    real = real_trace(w, chart)
    assert real["t_held_out"] == pytest.approx(chart.t[w.ho[0]]) and len(real["p"]) == len(chart.t)
    rec = {"system": "osc", "title": "oscillator", "names": {"lagsplat": "exact"}, "models": {"lagsplat": m}, "real": real}
    png = extrapolation_figure(rec, tmp_path / "figures" / "extrapolation.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000
    with pytest.raises(ValueError, match="no traces"):
        extrapolation_figure({**rec, "real": None}, tmp_path / "x.png")
