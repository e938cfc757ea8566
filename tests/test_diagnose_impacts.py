"""Impacts read off a 1-D motion: the stop's side and position, and the restitution (lagsplat.diagnose.impacts)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from lagsplat.diagnose.impacts import impact_signature, reversal_fit
from lagsplat.synth.realistic.impact_motion import impact_trajectory, observed_frequency

FPS = 30.0
T = np.arange(360) / FPS


def _impacts(e: float, stop: float, noise: float = 0.0, seed: int = 0) -> tuple[np.ndarray, float]:
    r = impact_trajectory(2 * math.pi * 0.8, 0.002, False, (stop,), e, 1.0 if stop < 0 else -1.0, 0.0, T)
    return r.x + noise * np.random.default_rng(seed).normal(size=len(T)), observed_frequency(r)


def test_reversal_fit_reads_the_speeds_on_either_side_of_a_kink():
    t = np.arange(-6, 7, dtype=float) - 0.3  # apex 0.3 frame after the middle sample
    p = np.where(t < 0, -2.0 * t, 1.2 * t) + 0.05 * t * t + 0.7  # one curvature on both sides
    tau, s0, v1, v2, _ = reversal_fit(p, 6)
    assert tau == pytest.approx(0.3, abs=0.05) and s0 == pytest.approx(0.7, abs=1e-3)
    assert v1 == pytest.approx(-2.0, rel=0.02) and v2 == pytest.approx(1.2, rel=0.02)
    with pytest.raises(ValueError, match="2 half"):
        reversal_fit(p[:-1], 6)


@pytest.mark.parametrize("e,stop", [(0.9, -0.4), (0.7, -0.2), (0.75, 0.6)])
def test_impacts_give_the_stop_side_position_and_restitution(e, stop):
    s, f = _impacts(e, stop)
    sig = impact_signature(s, [np.arange(len(s))], 1 / FPS, f)
    side = "lower" if stop < 0 else "upper"
    assert sig["stop_side"] == side
    assert sig[side]["s_stop"] == pytest.approx(stop, abs=0.02)
    assert sig[side]["restitution"] == pytest.approx(e, abs=0.05)
    lo, hi = sig[side]["restitution_90"]
    assert lo <= sig[side]["restitution"] <= hi
    other = sig["upper" if side == "lower" else "lower"]
    assert other["n_impacts"] == 0  # the free side turns smoothly


def test_stops_on_both_sides_count_together():
    """With a stop on each side the energy goes twice a cycle: two impacts a side, read together."""
    w0 = 2 * math.pi * 0.8
    r = impact_trajectory(w0, 0.002, False, (-0.5, 0.5), 0.7, 0.0, w0, T)
    s = r.x + 0.005 * np.random.default_rng(0).normal(size=len(T))
    sig = impact_signature(s, [np.arange(len(s))], 1 / FPS, observed_frequency(r))
    assert sig["upper"]["n_impacts"] == sig["lower"]["n_impacts"] == 2
    both = sig["both_sides"]
    assert both is not None and both["n_impacts"] == 4 and sig["stop_side"] in ("upper", "lower")
    assert both["restitution"] == pytest.approx(0.7, abs=0.05) and both["restitution_90"][0] <= both["restitution"] <= both["restitution_90"][1]
    assert both["evidence"] == pytest.approx(sig["upper"]["evidence"] + sig["lower"]["evidence"])
    assert sig["lower"]["s_stop"] == pytest.approx(-0.5, abs=0.03) and sig["upper"]["s_stop"] == pytest.approx(0.5, abs=0.03)


def test_noisy_impacts_still_name_the_side_and_bracket_the_restitution():
    s, f = _impacts(0.8, -0.4, noise=0.01)
    sig = impact_signature(s, [np.arange(len(s))], 1 / FPS, f)
    assert sig["stop_side"] == "lower"
    assert abs(sig["lower"]["restitution"] - 0.8) <= 0.1


@pytest.mark.parametrize("law", ["linear", "hardening"])
def test_smooth_oscillators_have_no_stop(law):
    w0 = 2 * math.pi * 0.8

    def rhs(_t, y):
        k = w0 * w0 * (y[0] + (0.5 * y[0] ** 3 if law == "hardening" else 0.0))
        return [y[1], -k - 2 * 0.01 * w0 * y[1]]

    x = solve_ivp(rhs, (0, T[-1]), [1.0, 0.0], t_eval=T, rtol=1e-9, atol=1e-12).y[0]
    x = x + 0.01 * np.random.default_rng(1).normal(size=len(x))
    sig = impact_signature(x, [np.arange(len(x))], 1 / FPS, 0.8)
    assert sig["stop_side"] is None and sig["both_sides"] is None
    assert sig["lower"]["n_impacts"] < 2 and sig["upper"]["n_impacts"] < 2


def _impact_chart(e: float, stop: float):
    """12 s of an impact oscillator (stop at ``stop``, released from the far side at 1) as a whitened 1-D chart."""
    from lagsplat.chart import Chart
    from lagsplat.io.clip import TRAIN

    r = impact_trajectory(2 * math.pi * 0.7, 0.002, False, (stop,), e, -math.copysign(1.0, stop), 0.0, T)
    q = (r.x - r.x.mean()) / r.x.std() + 0.01 * np.random.default_rng(3).standard_normal(len(T))
    n, eye = len(q), np.eye(1)
    chart = Chart(mean=np.zeros(1), W=eye, W_inv=eye, q=q[:, None], t=T, split=np.full(n, TRAIN, np.int8), G_bar=eye,
                  A=eye, ae_mse=np.zeros(n), ae_floor_train=0.0, ae_floor_held_out=0.0, height=64, width=64)  # fmt: skip
    return chart, (stop - r.x.mean()) / r.x.std()


def test_a_stop_struck_on_every_swing_is_an_end_stop_with_its_restitution():
    from lagsplat.diagnose import diagnose_chart
    from lagsplat.diagnose.oscillator import fit_linear_oscillator

    chart, s_stop = _impact_chart(0.6, -0.3)
    diag, _ = diagnose_chart(fit_linear_oscillator([chart.q], 1 / FPS), chart)
    assert diag.winner == "end_stop"
    imp = diag.effects[0].interpretation["impacts"]
    assert imp["restitution"] == pytest.approx(0.6, abs=0.1) and imp["s_stop"] == pytest.approx(s_stop, abs=0.05)
    assert "restitution" in diag.effects[0].interpretation["text"]


def test_stops_on_both_sides_with_few_impacts_are_an_end_stop():
    """Two stops, restitution 0.7: two impacts a side, together the evidence of a stop, read as one."""
    from lagsplat.chart import Chart
    from lagsplat.diagnose import diagnose_chart
    from lagsplat.diagnose.oscillator import fit_linear_oscillator
    from lagsplat.io.clip import TRAIN

    w0 = 2 * math.pi * 0.8
    r = impact_trajectory(w0, 0.002, False, (-0.5, 0.5), 0.7, 0.0, w0, T)
    q = (r.x - r.x.mean()) / r.x.std() + 0.005 * np.random.default_rng(0).standard_normal(len(T))
    n, eye = len(q), np.eye(1)
    chart = Chart(mean=np.zeros(1), W=eye, W_inv=eye, q=q[:, None], t=T, split=np.full(n, TRAIN, np.int8), G_bar=eye,
                  A=eye, ae_mse=np.zeros(n), ae_floor_train=0.0, ae_floor_held_out=0.0, height=64, width=64)  # fmt: skip
    diag, _ = diagnose_chart(fit_linear_oscillator([chart.q], 1 / FPS), chart)
    assert diag.winner == "end_stop"
    imp = diag.effects[0].interpretation["impacts"]
    assert imp["both_sides"] and imp["restitution"] == pytest.approx(0.7, abs=0.1)
    assert "stops on both sides" in diag.effects[0].interpretation["text"]


def test_a_struck_stop_is_not_held_to_the_r2_rule_but_to_the_others():
    from lagsplat.diagnose.diagnosis import failed_rules

    rule = (10.0, 0.1, 0.02)  # min_delta_bic, min_r2, min_cv_gain
    assert failed_rules(True, True, 54.0, 0.013, 0.007, 65.0, *rule, cv_gain_own=0.002) == ["r2"]
    assert failed_rules(True, True, 54.0, 0.013, 0.007, 65.0, *rule, cv_gain_own=0.002, struck=True) == []
    assert failed_rules(True, True, 5.0, 0.013, 0.007, 65.0, *rule, cv_gain_own=0.002, struck=True) == ["evidence"]
    assert failed_rules(True, True, 54.0, 0.013, 0.007, 65.0, *rule, cv_gain_own=-0.1, struck=True) == ["cv_gain"]
