"""Stage 2's multi-step (shooting) windows and loss, and the potential's spread kinks."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from lagsplat import timeseries
from lagsplat.chart import Chart
from lagsplat.dynamics.integrators import rollout, verlet_step
from lagsplat.io.clip import HELD_OUT, TRAIN
from lagsplat.models.icnn import ICNN
from lagsplat.models.lagrangian import Lagrangian
from lagsplat.train.shooting import multi_step_windows, shooting_loss
from lagsplat.train.stage2 import PAPER_FIT, Stage2Config, one_step_windows, train_stage2

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_one_step_shooting_windows_are_the_one_step_windows():
    rng = np.random.default_rng(0)
    q, u = rng.normal(size=(40, 2)), rng.normal(size=(40, 3))
    one = one_step_windows(q, 0.1, 2, u)
    q0, v0, Q, V, U = multi_step_windows(q, 0.1, 2, 1, u)
    for a, b in zip(one, (q0, v0, Q[:, 0], V[:, 0], U[:, 0], U[:, 1])):
        np.testing.assert_array_equal(a, b)


def test_multi_step_windows_follow_the_trajectory():
    t = np.arange(30) * 0.1
    q = np.stack([t**2, 3 * t], 1)  # central differences are exact on a quadratic
    q0, v0, Q, V, U = multi_step_windows(q, 0.1, 2, 3)
    assert q0.shape == (30 - 5 * 2, 2) and Q.shape == (20, 3, 2) and U.shape == (20, 4, 0)
    s = 4
    for j in range(1, 4):
        c = s + 2 + 2 * j
        np.testing.assert_allclose(Q[s, j - 1], q[c])
        np.testing.assert_allclose(V[s, j - 1], [2 * t[c], 3.0], atol=1e-12)
    np.testing.assert_allclose(v0[s], [2 * t[s + 2], 3.0], atol=1e-12)
    assert multi_step_windows(q[:10], 0.1, 2, 3)[0].shape == (0, 2)
    with pytest.raises(ValueError, match="K=0"):
        multi_step_windows(q, 0.1, 2, 0)


def test_shooting_loss_scores_every_chained_step():
    torch.manual_seed(0)
    model = Lagrangian(1, "scalar", 1.0, 0.2, (8, 8), 0.01, True)
    model.init_energy_scales(2 * math.pi, 0.01)
    q0, v0 = torch.tensor([[1.0], [0.5]]), torch.tensor([[0.0], [1.0]])
    Q, V = torch.zeros(2, 3, 1), torch.zeros(2, 3, 1)
    h, A = 0.05, torch.eye(1)
    got = shooting_loss(model, q0, v0, Q, V, torch.zeros(2, 4, 0), h, A, 0.1, 0.2)
    q, v, want = q0, v0, 0.0
    for _ in range(3):
        q, v = verlet_step(model, q, v, h)
        want = want + (0.1 * q[:, 0] ** 2 + 0.2 * (h * v[:, 0]) ** 2).mean()
    torch.testing.assert_close(got, want / 3)


def test_one_frame_velocities_and_substeps_match_the_frame_rate_verlet_map():
    """With ``k_v = 1`` the targets are one-frame central differences, and a step of ``h`` run as ``n`` sub-steps
    scores exactly what ``n`` chained steps of ``h / n`` give."""
    t = np.arange(30) * 0.1
    q = np.stack([t**3, 3 * t], 1)
    _, v0, _, V, _ = multi_step_windows(q, 0.1, 2, 2, k_v=1)
    c = 0 + 2 + 2
    np.testing.assert_allclose(V[0, 0], [(q[c + 1, 0] - q[c - 1, 0]) / 0.2, 3.0], atol=1e-12)
    with pytest.raises(ValueError, match="k_v=3"):
        multi_step_windows(q, 0.1, 2, 2, k_v=3)
    torch.manual_seed(0)
    model = Lagrangian(1, "scalar", 1.0, 0.2, (8, 8), 0.01, True)
    model.init_energy_scales(2 * math.pi, 0.01)
    q0, v0 = torch.tensor([[1.0]]), torch.tensor([[0.3]])
    Q, V, h, A = torch.zeros(1, 1, 1), torch.zeros(1, 1, 1), 0.1, torch.eye(1)
    got = shooting_loss(model, q0, v0, Q, V, torch.zeros(1, 2, 0), h, A, 1.0, 1.0, substeps=2)
    qa, va = verlet_step(model, *verlet_step(model, q0, v0, h / 2), h / 2)
    torch.testing.assert_close(got, (qa[0, 0] ** 2 + (h * va[0, 0]) ** 2))
    assert Stage2Config(stride=2, max_step_phase=0.5).substeps(1 / (9 * 0.1), 0.1) == 2  # 9 frames per period
    assert Stage2Config(stride=2, max_step_phase=0.5).substeps(1 / (30 * 0.1), 0.1) == 1  # 30 frames per period


def test_spread_kinks_put_each_kink_inside_the_data_and_keep_g_convex():
    x = torch.linspace(-2.0, 3.0, 200)[:, None]
    g = ICNN(1, (16, 16))
    g.spread_kinks(x, 30.0)
    for lin in g.inp:
        knots = -lin.bias / lin.weight[:, 0]
        assert bool(((knots > -2.0) & (knots < 3.0)).all())
        np.testing.assert_allclose(lin.weight.abs().detach().numpy(), 30.0 / 5.0, rtol=1e-5)
    y = g(torch.linspace(-4, 5, 401)[:, None]).detach().numpy()
    assert (np.diff(y, 2) > -1e-4).all()  # convex
    g2 = ICNN(3, (8,))
    g2.spread_kinks(torch.randn(50, 3), 10.0, seed=1)
    assert torch.allclose(g2.inp[0].weight.norm(dim=1) > 0, torch.tensor(True))
    with pytest.raises(ValueError, match="sharpness > 0"):
        g.spread_kinks(x, 0.0)
    with pytest.raises(ValueError, match=r"\[N>=2,1\]"):
        g.spread_kinks(torch.zeros(5, 2), 1.0)


def _end_stop_chart(dt: float = 1 / 30) -> tuple[Chart, float]:
    """An exact oscillator against a stiff one-sided wall (30x the spring) at -0.6 of its amplitude,
    two training episodes and a held-out one; returns the chart and the held-out frequency."""
    w0 = 2 * math.pi * 0.7

    def acc(x, v):
        return -w0**2 * x - 30 * w0**2 * min(0.0, x + 0.6) - 0.02 * w0 * v

    qs = []
    for amp in (1.0, 0.9, 0.95):
        x, v, out = amp, 0.0, []
        for _ in range(int(12 / dt)):
            for _ in range(20):  # substeps
                a = acc(x, v)
                v += a * dt / 20
                x += v * dt / 20
            out.append(x)
        qs.append(out)
    q = np.concatenate(qs)[:, None]
    n = len(q)
    episode = np.repeat([0, 1, 2], n // 3)
    split = np.where(episode < 2, TRAIN, HELD_OUT).astype(np.int8)
    I = np.eye(1)
    chart = Chart(mean=np.zeros(1), W=I, W_inv=I, q=q, t=np.arange(n) * dt, split=split, G_bar=I, A=I, ae_mse=np.zeros(n),
                  ae_floor_train=0.0, ae_floor_held_out=0.0, height=8, width=8, episode=episode)  # fmt: skip
    return chart, timeseries.spectral_peak_frequency(q[split == HELD_OUT], dt)


@pytest.mark.slow
def test_spread_kinks_and_shooting_follow_an_end_stop_the_default_smears():
    """The held-out frequency of an end stop's bouncing oscillation, as a user's rollout reads it: the
    paper's fit (all kinks at the origin, a scalar mass, one step per window) is stiffer than the truth;
    kinks spread over the range with a learned inertia and four-step windows come closer."""
    chart, f_true = _end_stop_chart()
    dt = float(chart.t[1] - chart.t[0])
    ho = np.flatnonzero(chart.split == HELD_OUT)

    def held_out_error(**kw) -> float:
        model, _ = train_stage2(chart, Stage2Config(epochs=60, windows_per_epoch=500, **kw), seed=0, progress=False)
        with torch.no_grad():
            r = rollout(model, torch.tensor(chart.q[ho[:1]], dtype=torch.float32), torch.zeros(1, 1), dt, len(ho))[0][0].numpy()
        return abs(timeseries.spectral_peak_frequency(r, dt) / f_true - 1)

    smooth = held_out_error(**PAPER_FIT)
    sharp = held_out_error(mass="learned", potential_kinks=30.0, rollout_steps=4)
    assert sharp < 0.5 * smooth, (sharp, smooth)


def test_kinks_are_spread_only_on_a_chart_without_a_logged_input(monkeypatch):
    """A kinked potential fits a logged input's force as a function of q (the free rollouts then fail), so a
    chart with an input keeps the smooth initialisation; one without gets the kinks at the configured sharpness."""
    import dataclasses

    calls = []
    monkeypatch.setattr(ICNN, "spread_kinks", lambda self, x, sharpness, seed=0: calls.append(float(sharpness)))
    chart, _ = _end_stop_chart()
    cfg = Stage2Config(epochs=1, windows_per_epoch=32)
    train_stage2(chart, cfg, seed=0, progress=False)
    assert calls == [cfg.potential_kinks] and cfg.potential_kinks > 0
    u = np.sin(np.arange(len(chart.q)) * 0.05)[:, None]
    train_stage2(dataclasses.replace(chart, u=u), cfg, seed=0, progress=False)
    assert calls == [cfg.potential_kinks]  # not called again


def test_alternative_kink_starts_keep_the_start_whose_rollouts_score_lowest():
    """``potential_kinks_alternatives``: one fit per sharpness from the same seed, the start with the lowest
    selection NRMSE returned (its weights and history), the others' scores recorded; a refit (``augment``)
    and the empty default train one start."""
    import dataclasses

    chart, _ = _end_stop_chart()
    base = Stage2Config(epochs=4, windows_per_epoch=64, select_every=2)
    alone = {s: train_stage2(chart, dataclasses.replace(base, potential_kinks=s), seed=0, progress=False) for s in (30.0, 0.0)}
    both_cfg = dataclasses.replace(base, potential_kinks_alternatives=(0.0, 30.0, 0.0))
    model, hist = train_stage2(chart, both_cfg, seed=0, progress=False)
    scores = {s: h["selected_nrmse"] for s, (_, h) in alone.items()}
    assert [(r["potential_kinks"], r["selected_nrmse"]) for r in hist["starts"]] == [(30.0, scores[30.0]), (0.0, scores[0.0])]
    kept = min(scores, key=scores.get)
    assert hist["potential_kinks"] == kept and hist["selected_nrmse"] == scores[kept]
    for (k, a), b in zip(alone[kept][0].state_dict().items(), model.state_dict().values()):
        torch.testing.assert_close(a, b, msg=k)
    assert "starts" not in train_stage2(chart, base, seed=0, progress=False)[1]
    seen = []
    _, h = train_stage2(chart, both_cfg, seed=0, progress=False, augment=lambda m: seen.append(m) or m)
    assert len(seen) == 1 and "starts" not in h


def test_auto_inertia_is_scalar_only_on_a_d1_chart_with_a_logged_input(tmp_path):
    """``mass="auto"``: the learned M(q) trades off against a logged input's actuation map on a d = 1 chart, so
    there the model is built with the scalar mass; elsewhere with the learned one. The saved model rebuilds
    with the same inertia and weights."""
    import dataclasses

    from lagsplat.train.stage2 import load_stage2, save_stage2

    cfg = Stage2Config(epochs=1, windows_per_epoch=32)
    assert cfg.mass == "auto"
    assert [cfg.build(d, n_u).mass_kind for d, n_u in ((1, 0), (1, 2), (2, 1), (3, 0))] == ["learned", "scalar", "learned", "learned"]
    assert Stage2Config(mass="constant").build(1, 1).mass_kind == "constant"  # an explicit choice is kept
    chart, _ = _end_stop_chart()
    u = np.sin(np.arange(len(chart.q)) * 0.05)[:, None]
    model, hist = train_stage2(dataclasses.replace(chart, u=u), cfg, seed=0, progress=False)
    assert model.mass_kind == "scalar" and model.mass_field is None
    save_stage2(tmp_path / "stage2.pt", model, cfg, hist)
    again, ck = load_stage2(tmp_path / "stage2.pt")
    assert again.mass_kind == "scalar" and ck["config"]["mass"] == "auto"
    for (k, a), (_, b) in zip(model.state_dict().items(), again.state_dict().items()):
        torch.testing.assert_close(a, b, msg=k)
