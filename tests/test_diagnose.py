"""Tests of the sim-to-real gap diagnosis at the latent level (lagsplat.diagnose).

No Stage 1: the true 1-D coordinate of a synthetic clip (lagsplat.synth.effects)
stands in for the chart, linearly mapped and with chart-like white noise; the
"plain model" is a linear damped oscillator fitted in closed form (the same
``acceleration`` / ``mass_matrix`` interface as the Lagrangian), or, once, a
briefly trained Lagrangian.
"""

from __future__ import annotations

import functools
import json
import math

import numpy as np
import pytest
import torch

from lagsplat.chart import Chart
from lagsplat.diagnose import (
    EFFECTS,
    LinearOscillator,
    diagnose_chart,
    effect_names,
    fit_linear_oscillator,
    residual_force,
    select_effect,
)
from lagsplat.diagnose.effect_terms import (
    CoulombFriction,
    CubicStiffness,
    EndStop,
    PeriodicForce,
    QuadraticDrag,
    StiffnessDampingDrift,
    term_from_spec,
)
from lagsplat.diagnose.filters import chart_noise
from lagsplat.diagnose.terms import (
    AugmentedLagrangian,
    build_term,
    delay_actuation,
    with_time_channel,
)
from lagsplat.io.clip import TRAIN
from lagsplat.models.lagrangian import Lagrangian
from lagsplat.synth.effects import simulate_effect

pytestmark = pytest.mark.usefixtures("one_torch_thread")

DT = 1 / 30.0


@functools.lru_cache(maxsize=None)
def _run(system: str, effect: str, seed: int, duration_s: float = 12.0):
    """The simulated clip, 2 training + 1 held-out episodes (cached: several tests read the same truth)."""
    return simulate_effect(system, effect, seed, duration_s=duration_s, n_episodes=3)


def _chart(system: str, effect: str, seed: int, noise: float = 0.01, duration_s: float = 12.0) -> Chart:
    """A 1-D chart from the true latent: a linear map (scale, sign, offset), whitening, white noise."""
    run = _run(system, effect, seed, duration_s)
    rng = np.random.default_rng(seed + 11)
    z = -1.7 * run.latent + 0.3
    tr = run.split == TRAIN
    q = (z - z[tr].mean()) / z[tr].std() + noise * rng.standard_normal(len(z))
    I = np.eye(1)
    return Chart(
        mean=np.zeros(1), W=I, W_inv=I, q=q[:, None], t=run.t, split=run.split, G_bar=I, A=I, ae_mse=np.zeros(len(q)),
        ae_floor_train=0.0, ae_floor_held_out=0.0, height=64, width=64, episode=run.episode, u=run.u,
    )  # fmt: skip


def _linear(chart: Chart) -> LinearOscillator:
    segs = chart.segments(TRAIN)
    return fit_linear_oscillator([chart.q[s] for s in segs], DT, [chart.u[s] for s in segs] if chart.n_u else None)


@functools.lru_cache(maxsize=None)
def _diagnosed(system: str, effect: str, seed: int, noise: float = 0.01):
    """``(diagnosis, residual)`` of the linear stand-in on a clip's training episodes (cached across tests)."""
    chart = _chart(system, effect, seed, noise=noise)
    return diagnose_chart(_linear(chart), chart)


# ------------------------------------------------------------------ residual
def test_residual_of_the_true_model_is_the_unmodelled_force() -> None:
    """On an exact linear oscillator plus a known extra force, r recovers the (smoothed) force, in force units."""
    w0, zeta, mu = 2 * math.pi * 0.7, 0.01, 0.6
    t = np.arange(900) * DT
    from scipy.integrate import solve_ivp

    def rhs(_t, y):
        return [y[1], -w0 * w0 * y[0] - 2 * zeta * w0 * y[1] - mu * math.tanh(y[1] / 0.02)]

    y = solve_ivp(rhs, (0, t[-1]), [1.0, 0.0], t_eval=t, rtol=1e-10, atol=1e-12, method="LSODA").y
    q = y[0][:, None]
    truth = LinearOscillator(np.array([[w0 * w0]]), np.array([[2 * zeta * w0]]), np.zeros(1))
    res = residual_force(truth, [q], DT)
    f_true = -mu * np.tanh(res.qdot[:, 0] / 0.02)
    smooth = res.features(lambda st: -mu * np.tanh(st.qdot[:, 0] / 0.02))[:, 0]
    assert np.corrcoef(res.r[:, 0], smooth)[0, 1] > 0.97
    assert abs(np.std(res.r[:, 0]) / np.std(smooth) - 1) < 0.1
    assert np.corrcoef(res.r[:, 0], f_true)[0, 1] > 0.9
    # without the extra force the residual is a small fraction of the model's force (smoothing bias only)
    y0 = solve_ivp(lambda _t, s: [s[1], -w0 * w0 * s[0] - 2 * zeta * w0 * s[1]], (0, t[-1]), [1.0, 0.0], t_eval=t, rtol=1e-10, atol=1e-12).y
    res0 = residual_force(truth, [y0[0][:, None]], DT)
    assert np.std(res0.r) < 0.02 * np.std(res0.f_model)
    assert res.n == res0.n == 900 - 2 * math.ceil(3 * res.sigma)


def test_noise_level_is_estimated() -> None:
    rng = np.random.default_rng(0)
    t = np.arange(2000) * DT
    x = np.sin(2 * math.pi * 0.8 * t)[:, None]
    for s in (0.003, 0.01, 0.03):
        est = chart_noise([x + s * rng.standard_normal(x.shape)])
        assert est[0] == pytest.approx(s, rel=0.12)


def test_residual_rejects_bad_input() -> None:
    m = LinearOscillator(np.eye(1), np.eye(1) * 0.1, np.zeros(1))
    with pytest.raises(ValueError, match="long enough"):
        residual_force(m, [np.zeros((10, 1))], DT)
    with pytest.raises(ValueError, match="NaN"):
        residual_force(m, [np.full((100, 1), np.nan)], DT)
    with pytest.raises(ValueError, match="dt"):
        residual_force(m, [np.zeros((100, 1))], 0.0)
    with pytest.raises(KeyError, match="unknown effect"):
        select_effect(residual_force(m, [np.sin(np.arange(200) * 0.2)[:, None]], DT), candidates=["gremlins"])


# ------------------------------------------------------------------ selection (linear stand-in)
@pytest.mark.parametrize(
    "effect",
    ["none", "coulomb", "quadratic_drag", "end_stop", "cubic_stiffness", "periodic_force", "drift", "actuation_delay", "missing_dof"],
)
def test_each_effect_is_ranked_first_on_the_cart(effect: str) -> None:
    diag, res = _diagnosed("cart", effect, 0)
    assert diag.winner == effect
    if effect == "none":
        assert diag.effects == [] and all(not f.significant for f in diag.ranking)
        assert 0.5 < diag.null["excess_over_noise"] < 1.5  # the residual is the chart noise
    else:
        assert diag.ranking[0].effect == effect and diag.ranking[0].significant
        assert diag.effects[0].delta_bic >= 10 and diag.effects[0].r2 >= 0.1
        assert np.all(np.isfinite(diag.effects[0].se))
    json.dumps(diag.to_dict(), allow_nan=False)  # report.json material: strict JSON
    assert "verdict" in diag.summary()


def test_fitted_coefficients_match_the_truth() -> None:
    """The diagnosed physical numbers agree with the simulated ones (unit-free comparisons)."""
    diag, _ = _diagnosed("cart", "periodic_force", 0)
    p = _run("cart", "periodic_force", 0).truth["effect_params"]
    assert diag.effects[0].params["f_hz"] == pytest.approx(p["f_hz"], rel=0.01)

    diag, _ = _diagnosed("cart", "actuation_delay", 0)
    tau = _run("cart", "actuation_delay", 0).truth["effect_params"]["tau_s"]
    assert diag.effects[0].params["tau_s"] == pytest.approx(tau, abs=DT / 2)

    diag, _ = _diagnosed("cart", "missing_dof", 0)
    run = _run("cart", "missing_dof", 0)
    assert diag.effects[0].params["f_hz"] == pytest.approx(run.truth["effect_params"]["f2_hz"], rel=0.05)

    diag, _ = _diagnosed("cart", "end_stop", 0)
    p = _run("cart", "end_stop", 0).truth["effect_params"]
    it = diag.effects[0].interpretation
    assert it["side"] == -p["side"] and it["stiffness_ratio"] > 5  # a stiff stop, on the mirrored side (the chart map flips the sign)
    # placed where the truth is, in chart units (_chart's map), as stiff, and with the samples past it counted,
    # all on the chart's own positions: the smoothed ones pull the turning points in (the stop sat 0.08 too
    # shallow, "0 % in contact", and the de-blurred ones still miss most of the bounce (stiffness 2.3x)
    run = _run("cart", "end_stop", 0)
    tr = run.split == TRAIN
    z = -1.7 * run.latent[tr] + 0.3
    assert it["s_stop"] == pytest.approx((-1.7 * p["x_stop"] + 0.3 - z.mean()) / z.std(), abs=0.05)
    in_contact = float(np.mean(p["side"] * (run.latent[tr] - p["x_stop"]) > 0))
    assert 0.7 * in_contact < it["fraction_in_contact"] < 1.3 * in_contact
    assert it["stiffness_ratio"] == pytest.approx(p["k_ratio"], rel=0.25)

    for seed, kind in ((0, "hardening"), (1, "softening")):
        diag, _ = _diagnosed("cart", "cubic_stiffness", seed)
        it = diag.effects[0].interpretation
        eps = _run("cart", "cubic_stiffness", seed).truth["effect_params"]["eps"]
        assert it["kind"] == kind and abs(it["k3"]) > 3 * it["k3_se"]
        # relative shift at the largest amplitude against the truth 3 eps (A_max / A)^2 / 8, within 30 %
        run = _run("cart", "cubic_stiffness", seed)
        a_max = np.quantile(np.abs(run.x[run.split == TRAIN]), 0.99) / run.truth["amplitude"]
        assert it["relative_frequency_shift_at_amplitude"] == pytest.approx(3 * eps * a_max**2 / 8, rel=0.3)


def test_signatures_read_the_envelope_and_frequency_shift() -> None:
    assert _diagnosed("cart", "coulomb", 0)[0].evidence["envelope"]["best"] == "linear"
    assert _diagnosed("cart", "none", 0)[0].evidence["envelope"]["best"] == "exponential"
    assert _diagnosed("cart", "cubic_stiffness", 0)[0].evidence["frequency"]["z_amp2"] > 3  # hardening: f rises with amplitude
    assert _diagnosed("cart", "cubic_stiffness", 1)[0].evidence["frequency"]["z_amp2"] < -3  # softening
    assert abs(_diagnosed("cart", "drift", 0)[0].evidence["frequency"]["z_time"]) > 3  # stiffness drift: f changes with time
    spec = _diagnosed("cart", "periodic_force", 0)[0].evidence["spectrum"]
    f = _run("cart", "periodic_force", 0).truth["effect_params"]["f_hz"]
    assert any(abs(p - f) < 0.05 * f for p in spec["unexplained_peaks_hz"])


def test_a_distorted_chart_of_an_isochronous_motion_is_not_a_cubic_stiffness() -> None:
    """A chart q = s + b s^3 makes a linear oscillator anharmonic in q, but not in time (its periods stay put).

    In q the waveform carries a Duffing-like cubic (the linear stand-in leaves a large cubic residual), so
    only the recorded timing tells the two apart: the cubic candidate is rejected for its zero-crossing
    periods, which do not shift with amplitude, while a true hardening through a linear chart is kept.
    """
    run = _run("cart", "none", 0)
    tr = run.split == TRAIN
    s = (run.latent - run.latent[tr].mean()) / run.latent[tr].std()
    q = s + 0.08 * s**3
    q = (q - q[tr].mean()) / q[tr].std() + 0.01 * np.random.default_rng(3).standard_normal(len(q))
    base = _chart("cart", "none", 0)
    chart = Chart(**{**base.__dict__, "q": q[:, None]})
    diag, _ = diagnose_chart(_linear(chart), chart)
    assert diag.winner == "none", diag.summary()
    cubic = next(f for f in diag.ranking if f.effect == "cubic_stiffness")
    assert cubic.delta_bic > 10 and abs(cubic.interpretation["relative_frequency_shift_at_amplitude"]) >= 0.03  # big in q...
    assert abs(cubic.interpretation["measured_frequency_shift"]) < 0.015  # ...but the periods do not move
    assert "recorded periods" in cubic.interpretation["below_practical_size"]
    assert _diagnosed("cart", "cubic_stiffness", 0)[0].winner == "cubic_stiffness"


def test_a_cubic_stiffness_on_too_few_periods_to_check_its_timing_says_so() -> None:
    """On one training take of about three periods the frequency is not regressed on amplitude and time, so a cubic
    found in the residual is not checked against the recorded periods, and a drifting stiffness would read the same."""
    base = _chart("cart", "cubic_stiffness", 0, duration_s=4.0)
    chart = Chart(**{**base.__dict__, "split": np.where(base.episode == 0, TRAIN, 1 - TRAIN).astype(base.split.dtype)})
    diag, _ = diagnose_chart(_linear(chart), chart)
    cubic = next(f for f in diag.ranking if f.effect == "cubic_stiffness")
    assert diag.evidence["frequency"]["n_periods"] < 6 and cubic.interpretation["measured_frequency_shift"] is None
    assert "not checked against the recorded periods (3 periods, 6 needed)" in cubic.interpretation["text"]
    full = next(f for f in _diagnosed("cart", "cubic_stiffness", 0)[0].ranking if f.effect == "cubic_stiffness")
    assert full.interpretation["measured_frequency_shift"] is not None and "not checked" not in full.interpretation["text"]


def test_pendulum_effects_and_control_with_the_linear_stand_in() -> None:
    for effect in ("none", "coulomb", "missing_dof"):
        chart = _chart("pendulum", effect, seed=1)
        diag, _ = diagnose_chart(_linear(chart), chart)
        assert diag.winner == effect, (effect, diag.summary())


def test_quadratic_drag_is_found_on_the_wide_residual_and_the_control_stays_clean() -> None:
    """Out-of-class candidates are fitted at 1.5x the smoothing (lagsplat.diagnose.residual, "Smoothing width").

    At 2 % chart noise the drag (most of the energy loss) is buried in the
    differentiated noise of the sharp residual and missed there; on the wide one it
    is found, while the control at the same noise stays "nothing significant".
    """
    from lagsplat.diagnose import residual_from_chart

    chart = _chart("pendulum", "quadratic_drag", seed=1, noise=0.02)
    model = _linear(chart)
    diag, res = diagnose_chart(model, chart)
    assert res.wide is not None and res.wide.sigma == pytest.approx(1.5 * res.sigma) and res.wide.wide is None
    assert diag.settings["sigma_frames_out_of_class"] == pytest.approx(res.wide.sigma)
    assert diag.null["out_of_class"]["sigma_frames"] == pytest.approx(res.wide.sigma)
    assert diag.winner == "quadratic_drag", diag.summary()
    assert diag.effects[0].coef[0] > 3 * diag.effects[0].se[0]
    assert diag.effects[0].delta_bic >= 10  # the wide residual's regression finds it on its own
    sharp = select_effect(residual_from_chart(model, chart, wide_factor=None))
    assert sharp.settings["sigma_frames_out_of_class"] == pytest.approx(res.sigma)
    # on the sharp residual the regression alone misses it; the decay of the whole trajectory carries it (more sharply
    # than the hyperbolic envelope of the turning points, which also favours it)
    drag = next(f for f in sharp.ranking if f.effect == "quadratic_drag")
    assert drag.delta_bic < 10 <= drag.evidence and drag.signature_support > 0
    assert sharp.evidence["envelope"]["support"]["hyperbolic"] > 0
    assert drag.signature_support == pytest.approx(sharp.evidence["decay_law"]["drag"]["evidence"])
    assert "whole trajectory decays as quadratic drag" in drag.interpretation["signature"]
    # the reported null is the sharp residual's either way
    assert diag.null["excess_over_noise"] == pytest.approx(sharp.null["excess_over_noise"])
    control = _chart("pendulum", "none", seed=1, noise=0.02)
    assert diagnose_chart(_linear(control), control)[0].winner == "none"


def test_control_with_a_trained_lagrangian_is_not_flagged_and_friction_is() -> None:
    """The paper's model, briefly fitted by Stage 2, as the plain model (its potential misfit must not be flagged)."""
    from lagsplat.train.stage2 import PAPER_FIT, Stage2Config, train_stage2

    for effect in ("none", "coulomb"):
        chart = _chart("cart", effect, seed=0)
        model, _ = train_stage2(chart, Stage2Config(epochs=6, windows_per_epoch=500, **PAPER_FIT), seed=0, progress=False)
        diag, _ = diagnose_chart(model, chart)
        assert diag.winner == effect, diag.summary()


# ------------------------------------------------------------------ terms
def test_dissipative_terms_never_inject_energy() -> None:
    g = torch.Generator().manual_seed(0)
    for d in (1, 3):
        q = 3 * torch.randn(4000, d, generator=g)
        qd = 3 * torch.randn(4000, d, generator=g)
        e = torch.randn(d, generator=g)
        for term in (CoulombFriction(e, 0.7, 0.05), QuadraticDrag(e, 1.3)):
            with torch.no_grad():
                term.raw.fill_(-3.0 + 6.0 * torch.rand((), generator=g).item())
            with torch.no_grad():
                p = (qd * term(q, qd)).sum(-1)
            assert float(p.max()) <= 0.0
        # the drift's damping part stays above -c_floor: with the floor c0 the total power is <= -(c0 - c_floor)|qdot|^2
        drift = StiffnessDampingDrift(e, 0.0, -5.0, t_ref=0.0, s0=0.0, c_floor=0.5, k_floor=0.0)
        t = 100 * torch.rand(4000, generator=g)
        c0 = 1.0
        with torch.no_grad():
            p = (qd * (drift(q, qd, t) - c0 * qd)).sum(-1)
        e_hat = e / e.norm()
        assert float((p + (c0 - 0.5) * (qd @ e_hat) ** 2).max()) <= 1e-4


def test_conservative_terms_derive_from_their_potential() -> None:
    torch.manual_seed(0)
    e = torch.tensor([0.6, -0.8])
    for term in (EndStop(e, 5.0, 0.3, -1.0), CubicStiffness(e, 2.0, 0.1, 3.0), CubicStiffness(e, -2.0, 0.1, 3.0)):
        q = torch.randn(256, 2, dtype=torch.float64, requires_grad=True)
        term = term.double()
        V = term.potential(q)
        (grad,) = torch.autograd.grad(V.sum(), q)
        torch.testing.assert_close(term(q.detach(), torch.zeros_like(q)), -grad, rtol=1e-6, atol=1e-8)
    # the softening form saturates: it falls only logarithmically, so any quadratic floor keeps the total coercive
    soft = CubicStiffness(torch.ones(1), -50.0, 0.0, 1.0).double()
    x = torch.logspace(0, 6, 61, dtype=torch.float64)[:, None]
    with torch.no_grad():
        total = 0.01 * 0.5 * x[:, 0] ** 2 + soft.potential(x)
    assert bool(torch.all(torch.diff(total[-20:]) > 0)) and float(total[-1]) > 1e8
    with torch.no_grad():
        assert float(soft(torch.tensor([[1e3]], dtype=torch.float64), torch.zeros(1, 1, dtype=torch.float64)).abs()) < 1.0  # force decays


def test_augmented_lagrangian_energy_decreases_and_terms_enter_the_rhs() -> None:
    torch.manual_seed(0)
    base = Lagrangian(2, "scalar", c0=0.05).eval()
    terms = [CoulombFriction(torch.tensor([1.0, 0.0]), 0.3, 0.05), QuadraticDrag(torch.tensor([0.0, 1.0]), 0.2),
             EndStop(torch.tensor([1.0, 1.0]), 4.0, 0.2, 1.0), CubicStiffness(torch.tensor([1.0, -1.0]), -0.5, 0.0, 3.0)]  # fmt: skip
    aug = AugmentedLagrangian(base, terms).eval()
    q = torch.randn(64, 2, requires_grad=True)
    qd = torch.randn(64, 2, requires_grad=True)
    E = aug.energy(q, qd)
    gq, gv = torch.autograd.grad(E.sum(), (q, qd))
    qdd = aug.acceleration(q.detach(), qd.detach())
    dE = (gq * qd).sum(-1) + (gv * qdd).sum(-1)
    assert float(dE.detach().max()) <= 1e-4
    # the terms enter exactly like an external force
    f = sum(t(q.detach(), qd.detach()) for t in terms)
    torch.testing.assert_close(aug.acceleration(q.detach(), qd.detach()), base.acceleration(q.detach(), qd.detach(), f), rtol=1e-5, atol=1e-5)
    # and the integrators take the augmented model as it is: a free rollout loses energy
    from lagsplat.dynamics.integrators import rollout

    with torch.no_grad():
        qs, vs = rollout(aug, q.detach()[:8], qd.detach()[:8], 0.01, 400)
        E = torch.stack([aug.energy(qs[:, i], vs[:, i]) for i in range(0, 400, 20)], 1)
    assert torch.isfinite(E).all() and bool((E[:, -1] < E[:, 0]).all())
    assert float((E[:, 1:] - E[:, :-1]).max()) < 1e-3 * float(E[:, 0].abs().max())


def test_time_channel_and_periodic_term() -> None:
    base = LinearOscillator(np.eye(1) * 4.0, np.eye(1) * 0.1, np.zeros(1))
    per = PeriodicForce(torch.ones(1), 0.5, 2.0, -1.0).double()
    aug = AugmentedLagrangian(base, [per], time_channel=True)
    q, qd = torch.zeros(3, 1, dtype=torch.float64), torch.zeros(3, 1, dtype=torch.float64)
    t = torch.tensor([0.0, 0.5, 1.0], dtype=torch.float64)
    a = aug.acceleration(q, qd, u=t[:, None])
    expect = 2.0 * torch.cos(2 * math.pi * 0.5 * t) - 1.0 * torch.sin(2 * math.pi * 0.5 * t)
    torch.testing.assert_close(a[:, 0], expect)
    with pytest.raises(ValueError, match="time"):
        AugmentedLagrangian(base, [per], time_channel=False)
    chart = _chart("cart", "none", seed=0, duration_s=4.0)
    tc = with_time_channel(chart)
    assert tc.u.shape == (len(chart.t), 1) and np.allclose(tc.u[:, 0], chart.t, atol=1e-4) and chart.u.shape[1] == 0


def test_delay_actuation_shifts_the_input() -> None:
    t = np.arange(100) * 0.01
    u = np.stack([t, t**2], 1)
    out = delay_actuation(u, t, 0.05)
    np.testing.assert_allclose(out[10:, 0], t[10:] - 0.05, atol=1e-6)
    assert out[0, 0] == pytest.approx(0.0)
    with pytest.raises(ValueError):
        delay_actuation(u, t, -0.1)


def test_build_term_starts_at_the_diagnosed_values() -> None:
    diag, res = _diagnosed("cart", "coulomb", 0)
    fit = diag.effects[0]
    term = build_term(fit)
    assert isinstance(term, CoulombFriction)
    assert term.mu.item() == pytest.approx(fit.coef[0], rel=1e-4)
    assert term.spec()["mu"] == pytest.approx(fit.coef[0], rel=1e-4) and term.spec()["class"] == "CoulombFriction"
    f = term(torch.as_tensor(res.q[:50]), torch.as_tensor(res.qdot[:50])).detach().numpy()
    np.testing.assert_allclose(f[:, 0], -fit.coef[0] * np.tanh(res.qdot[:50, 0] / fit.params["v_s"]), rtol=1e-4, atol=1e-6)
    assert set(effect_names()) == {e.name for e in EFFECTS}
    # every term survives a round trip through its spec (what a checkpoint would store)
    e = torch.tensor([0.6, 0.8])
    q, qd, t = torch.randn(20, 2), torch.randn(20, 2), torch.rand(20) * 30
    for term in (CoulombFriction(e, 0.3, 0.1), QuadraticDrag(e, 0.2), EndStop(e, 3.0, 0.1, -1.0), CubicStiffness(e, -0.4, 0.1, 2.0),
                 PeriodicForce(e, 1.3, 0.2, -0.1), StiffnessDampingDrift(e, 0.01, -0.02, 10.0, 0.0, 0.5, 1.0)):  # fmt: skip
        again = term_from_spec(term.spec())
        torch.testing.assert_close(again(q, qd, t), term(q, qd, t))
    with pytest.raises(KeyError):
        term_from_spec({"class": "Gremlin"})


def test_two_dimensional_chart_finds_the_effect_and_its_direction() -> None:
    """d = 2: friction on one of two independent oscillators, seen through a rotated chart."""
    a, b = _run("cart", "coulomb", 0), _run("cart", "none", 1)
    ang = math.radians(35.0)
    R = np.array([[math.cos(ang), math.sin(ang)], [-math.sin(ang), math.cos(ang)]])
    X = np.stack([a.latent / a.latent.std(), b.latent / b.latent.std()], 1)
    q = X @ R + 0.01 * np.random.default_rng(3).standard_normal(X.shape)
    I = np.eye(2)
    chart = Chart(
        mean=np.zeros(2), W=I, W_inv=I, q=q, t=a.t, split=a.split, G_bar=I, A=I, ae_mse=np.zeros(len(q)),
        ae_floor_train=0.0, ae_floor_held_out=0.0, height=64, width=64, episode=a.episode, u=a.u,
    )  # fmt: skip
    diag, res = diagnose_chart(_linear(chart), chart, candidates=["coulomb", "quadratic_drag", "cubic_stiffness", "drift"])
    assert res.d == 2 and diag.winner == "coulomb", diag.summary()
    e = diag.effects[0].direction
    assert abs(float(e @ R[0])) > math.cos(math.radians(10.0))  # the friction acts along the first oscillator's coordinate
    # the control direction alone carries nothing
    chart_b = Chart(
        mean=np.zeros(1), W=np.eye(1), W_inv=np.eye(1), q=q @ R[1][:, None], t=a.t, split=a.split, G_bar=np.eye(1), A=np.eye(1),
        ae_mse=np.zeros(len(q)), ae_floor_train=0.0, ae_floor_held_out=0.0, height=64, width=64, episode=a.episode, u=a.u,
    )  # fmt: skip
    assert diagnose_chart(_linear(chart_b), chart_b)[0].winner == "none"


def test_harmonics_of_the_recorded_motion_are_not_sought_as_modes_or_forces() -> None:
    """A hidden mode / periodic force is not sought at 2x the *recorded* oscillation frequency even when the
    model's linearised mode is a few percent off (blind-suite control cart-none-1: mode 0.779 Hz, motion 0.753 Hz,
    a 1.465 Hz chart harmonic was taken for a hidden mode)."""
    from types import SimpleNamespace

    from lagsplat.diagnose.spectrum import frequency_allowed

    dt = 1 / 30
    res = SimpleNamespace(meta={"model_freqs_hz": [0.779]}, f_dominant_hz=0.753, dt=dt, n_u=0,
                          states=[SimpleNamespace(t=np.arange(180) * dt)])  # fmt: skip
    assert not frequency_allowed(res, 1.465)  # 1.95x the motion: its 2nd harmonic
    assert not frequency_allowed(res, 1.56)  # 2x the model's mode
    assert frequency_allowed(res, 1.15) and frequency_allowed(res, 1.85)  # 1.5x and 2.45x the motion: where the suite's hidden modes lie
    res.meta["model_freqs_hz"], res.f_dominant_hz = [0.8], 0.8  # model and motion at 0.8 Hz: 1.465 Hz is 1.83x, sought again
    assert frequency_allowed(res, 1.465)


def test_a_periodic_force_too_small_to_move_the_object_is_not_a_finding() -> None:
    """The periodic force's size rule: the motion it drives off resonance, over the recorded motion (both rms)."""
    run = _run("cart", "periodic_force", 0)
    p = run.truth["effect_params"]
    r = p["f_hz"] / run.truth["f0_hz"]
    s = run.latent[run.split == TRAIN]
    # force per unit mass p["amplitude"] = kappa w0^2 A (lagsplat.synth.effects): driven amplitude kappa A / |1 - r^2|
    expected = p["kappa"] * run.truth["amplitude"] / abs(1 - r * r) / math.sqrt(2) / s.std()
    diag, res = _diagnosed("cart", "periodic_force", 0)
    assert diag.winner == "periodic_force"
    fit = diag.effects[0]
    assert fit.practical
    assert fit.interpretation["driven_over_motion"] == pytest.approx(expected, rel=0.3)
    # the same residual, with the size rule set above it: still significant, no longer a finding
    strict = select_effect(res, min_periodic_response=2 * expected, model_freqs_hz=res.meta.get("model_freqs_hz"))
    assert strict.winner != "periodic_force"
    rejected = next(f for f in strict.ranking if f.effect == "periodic_force")
    assert not rejected.practical and "below" in rejected.interpretation["below_practical_size"]


def _bilinear_spring_chart(ratio: float, kink: float) -> Chart:
    """12 s of a spring ``ratio`` times stiffer beyond ``x = kink`` (rest at 0, released from ``x = -1``), as a whitened chart."""
    from scipy.integrate import solve_ivp

    w0, zeta = 2 * math.pi * 0.7, 0.01
    t = np.arange(int(12 / DT)) * DT

    def rhs(_t, y):
        return [y[1], -w0 * w0 * y[0] - (ratio - 1) * w0 * w0 * max(y[0] - kink, 0.0) - 2 * zeta * w0 * y[1]]

    x = solve_ivp(rhs, (0, t[-1]), [-1.0, 0.0], t_eval=t, rtol=1e-10, atol=1e-12, method="LSODA", max_step=DT / 4).y[0]
    q = (x - x.mean()) / x.std() + 0.01 * np.random.default_rng(0).standard_normal(len(x))
    n, I = len(q), np.eye(1)
    return Chart(mean=np.zeros(1), W=I, W_inv=I, q=q[:, None], t=t, split=np.full(n, TRAIN, np.int8), G_bar=I,
                 A=I, ae_mse=np.zeros(n), ae_floor_train=0.0, ae_floor_held_out=0.0, height=64, width=64)  # fmt: skip


def test_a_kink_inside_the_range_of_motion_is_a_bilinear_spring_not_an_end_stop() -> None:
    # a stop limits the range from a gap beyond rest; a spring 10x stiffer past a point on the near side of rest
    # is touched on ~30 % of the samples: the one-sided feature fits it overwhelmingly, but it is not a stop
    bilinear = _bilinear_spring_chart(10.0, -0.2)
    diag, _ = diagnose_chart(_linear(bilinear), bilinear)
    stop = next(f for f in diag.ranking if f.effect == "end_stop")
    assert stop.delta_bic > 100 and stop.interpretation["fraction_in_contact"] > 0.25 and stop.interpretation["stiffness_ratio"] > 2
    assert diag.winner != "end_stop" and not stop.practical and "inside the range" in stop.interpretation["below_practical_size"]
    loose, _ = diagnose_chart(_linear(bilinear), bilinear, max_stop_contact_fraction=1.0)
    assert loose.winner == "end_stop"  # without the contact rule it would be reported as a stop
    # the same spring with its kink at a gap beyond rest, as a stop sits: touched briefly, and named
    gap = _bilinear_spring_chart(20.0, 0.6)
    diag, _ = diagnose_chart(_linear(gap), gap)
    assert diag.winner == "end_stop" and diag.effects[0].interpretation["fraction_in_contact"] < 0.15


def _first_periods(chart: Chart, periods: float) -> Chart:
    """The first ``periods`` periods of ``chart``'s first training episode, all training frames (a short clip)."""
    from lagsplat.timeseries import spectral_peak_frequency

    seg = chart.segments(TRAIN)[0]
    n = int(round(periods / spectral_peak_frequency(chart.q[seg], DT) / DT))
    sl, I = seg[:n], np.eye(1)
    return Chart(mean=np.zeros(1), W=I, W_inv=I, q=chart.q[sl], t=chart.t[sl] - chart.t[sl][0], split=np.full(n, TRAIN, np.int8), G_bar=I,
                 A=I, ae_mse=np.zeros(n), ae_floor_train=0.0, ae_floor_held_out=0.0, height=64, width=64)  # fmt: skip


def test_three_periods_of_training_frames_still_cross_validate() -> None:
    # at two periods a block, three periods made one block: every CV gain read 0 and nothing could be significant
    stop = _first_periods(_chart("cart", "end_stop", 0), 3.0)
    diag, _ = diagnose_chart(_linear(stop), stop)
    assert diag.settings["cv_folds"] >= 2 and diag.winner == "end_stop" and diag.ranking[0].cv_gain > 0.5
    control = _first_periods(_chart("cart", "none", 0), 3.0)
    diag, _ = diagnose_chart(_linear(control), control)
    assert diag.settings["cv_folds"] >= 2 and diag.winner == "none"


def test_a_residual_too_short_for_two_folds_says_so() -> None:
    from lagsplat.diagnose.regression import Regression, blocked_folds, n_cv_folds

    stop = _first_periods(_chart("cart", "end_stop", 0), 3.0)
    _, res = diagnose_chart(_linear(stop), stop)
    assert n_cv_folds(blocked_folds(res, 5, None)) == 3  # the short clip's blocks shrink to three
    one = blocked_folds(res, 5, block_s=1e3)  # a block longer than the clip: one fold
    assert n_cv_folds(one) == 1
    reg = Regression(res, one, res.r, np.ones((res.n, 1)), ())
    assert math.isnan(reg.cv_sse(None, False))
