"""The latent neural ODE baseline (lagsplat.baselines.neural_ode): it learns what the windows show, with no prior."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from lagsplat.baselines import LatentNeuralODE, ode_rollout, train_neural_ode
from lagsplat.chart import Chart
from lagsplat.io.clip import HELD_OUT, TRAIN
from lagsplat.timeseries import spectral_peak_frequency
from lagsplat.train.stage2 import Stage2Config

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _oscillator_chart(f_hz: float = 1.0, zeta: float = 0.05, seconds: float = 16.0, dt: float = 1 / 30) -> Chart:
    """Exact states of a damped linear oscillator, started at several amplitudes (three training episodes, one held out)."""
    w = 2 * math.pi * f_hz
    wd = w * math.sqrt(1 - zeta**2)
    t = np.arange(int(seconds / dt)) * dt
    qs, ep = [], []
    for k, a in enumerate((1.5, -1.0, 0.7, 1.2)):
        qs.append(a * np.exp(-zeta * w * t) * (np.cos(wd * t) + zeta * w / wd * np.sin(wd * t)))
        ep.append(np.full(len(t), k))
    q = np.concatenate(qs)[:, None]
    n = len(q)
    split = np.where(np.concatenate(ep) < 3, TRAIN, HELD_OUT).astype(np.int8)
    I = np.eye(1)
    return Chart(mean=np.zeros(1), W=I, W_inv=I, q=q, t=np.concatenate([t + 100 * k for k in range(4)]), split=split, G_bar=I, A=I,
                 ae_mse=np.zeros(n), ae_floor_train=0.0, ae_floor_held_out=0.0, height=8, width=8, episode=np.concatenate(ep))  # fmt: skip


def test_the_field_is_unconstrained_and_integrates_exactly_a_known_one() -> None:
    model = LatentNeuralODE(1, 0, hidden=())  # one linear layer: d(q, v)/dt = W (q, v) + b
    with torch.no_grad():
        model.net[0].weight.copy_(torch.tensor([[0.0, 1.0], [-(2 * math.pi) ** 2, 0.0]]))  # an undamped 1 Hz oscillator
        model.net[0].bias.zero_()
    q = ode_rollout(model, torch.ones(1, 1), torch.zeros(1, 1), 1 / 30, 61)
    assert q[0, 15, 0].item() == pytest.approx(-1.0, abs=1e-3) and q[0, 30, 0].item() == pytest.approx(1.0, abs=2e-3)  # half and one period
    assert sum(p.numel() for p in LatentNeuralODE(2, 1, (8,)).parameters()) == (4 + 1) * 8 + 8 + 8 * 4 + 4


def test_it_recovers_a_linear_oscillator_from_exact_states() -> None:
    chart = _oscillator_chart()
    cfg = Stage2Config(epochs=80, windows_per_epoch=400, lr=1e-2, hidden=(32, 32), select_every=10)
    model, hist = train_neural_ode(chart, cfg, seed=0)
    assert hist["selected_nrmse"] < 0.1 and hist["loss"][-1] < hist["loss"][0]
    ho = np.flatnonzero(chart.split == HELD_OUT)
    q_true = chart.q[ho]
    dt = 1 / 30
    q0, v0 = torch.tensor(q_true[:1], dtype=torch.float32), torch.zeros(1, 1)  # the held-out episode starts at rest, amplitude 1.2
    pred = ode_rollout(model, q0, v0, dt, 240)[0, :, 0].numpy()
    nrmse = float(np.sqrt(np.mean((pred - q_true[:240, 0]) ** 2)) / q_true[:240, 0].std())
    assert nrmse < 0.15  # 8 s (8 periods) of an episode it never saw
    assert spectral_peak_frequency(pred[:, None], dt) == pytest.approx(1.0, rel=0.05)
