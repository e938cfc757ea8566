"""The chart-invariant signatures as evidence (lagsplat.diagnose.signatures, select.decide, refit_choice).

A linear envelope of the turning points and a rest off the centre of the oscillation are how a
physicist tells dry friction from viscous damping; the diagnosis adds their evidence to the
candidate's Delta BIC. The trajectories here are integrated directly (no Stage 1): a 0.8 Hz
oscillator with dry friction, which sticks at -0.94 mu / k, and one with viscous damping only.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from lagsplat.chart import Chart
from lagsplat.diagnose import diagnose_chart, fit_linear_oscillator
from lagsplat.diagnose.diagnosis import CandidateFit, Diagnosis
from lagsplat.diagnose.refit_choice import choose_by_refit
from lagsplat.diagnose.select import decide, signature_confirmed
from lagsplat.io.clip import TRAIN

pytestmark = pytest.mark.usefixtures("one_torch_thread")

DT = 1 / 30.0


def _chart(q: np.ndarray, t: np.ndarray, G_bar: np.ndarray | None = None, episode: np.ndarray | None = None) -> Chart:
    """An all-training chart of ``q [n,d]`` at times ``t [n]`` (identity whitening, no AE error)."""
    n, d = q.shape
    I = np.eye(d)
    return Chart(mean=np.zeros(d), W=I, W_inv=I, q=q, t=t, split=np.full(n, TRAIN, np.int8), G_bar=I if G_bar is None else G_bar,
                 A=I, ae_mse=np.zeros(n), ae_floor_train=0.0, ae_floor_held_out=0.0, height=64, width=64, episode=episode)  # fmt: skip


def _oscillator(x0: float, mu_over_k: float, zeta: float, duration_s: float = 12.0, f_hz: float = 0.8) -> tuple[Chart, np.ndarray]:
    """``x'' = -w^2 x - 2 zeta w x' - w^2 (mu / k) sign(x')``, sticking once ``|x| <= mu / k`` at a reversal; a 1-D chart of it."""
    w, sub = 2 * math.pi * f_hz, 20
    h = DT / sub
    x, v, xs = x0, 0.0, []
    for _ in range(int(round(duration_s / DT))):
        xs.append(x)
        for _ in range(sub):
            if v == 0.0 and abs(x) <= mu_over_k:
                continue  # stuck: static friction holds the spring
            v_new = v + h * (-w * w * x - 2 * zeta * w * v - w * w * mu_over_k * np.sign(v if v != 0.0 else -x))
            if v != 0.0 and np.sign(v_new) != np.sign(v) and abs(x) <= mu_over_k:
                v_new = 0.0
            v, x = v_new, x + h * v_new
    x = np.asarray(xs)
    q = x / x.std() + 0.01 * np.random.default_rng(0).standard_normal(len(x))
    return _chart(q[:, None], np.arange(len(q)) * DT), x


def _diagnose(chart: Chart) -> Diagnosis:
    model = fit_linear_oscillator([chart.q[s] for s in chart.segments(TRAIN)], DT)
    return diagnose_chart(model, chart)[0]


def test_dry_friction_shows_a_linear_envelope_and_an_off_centre_rest() -> None:
    chart, x = _oscillator(1.05, 0.035, 0.005)
    assert x[-1] == pytest.approx(-0.94 * 0.035, abs=0.003)  # the truth: stuck off-centre, within mu / k
    diag = _diagnose(chart)
    env, rest = diag.evidence["envelope"], diag.evidence["rest"]
    assert env["best"] == "linear" and env["support"]["linear"] >= 10 and env["support"]["hyperbolic"] < 0
    assert rest["at_rest"] and abs(rest["offset_over_noise"]) > 5 and rest["support"] > 10
    assert 7.0 < rest["rest_time_s"] < 9.0
    assert rest["rest_position"] == pytest.approx(x[-1] / x.std(), abs=0.01)  # chart units
    law = diag.evidence["decay_law"]["dry"]  # the whole trajectory reads the decay more sharply than the turning points
    assert law["sign_ok"] and law["evidence"] > env["support"]["linear"]
    assert not (diag.evidence["decay_law"]["drag"]["sign_ok"] and diag.evidence["decay_law"]["drag"]["evidence"] > 0)
    coulomb = next(f for f in diag.ranking if f.effect == "coulomb")
    assert coulomb.signature_support == pytest.approx(law["evidence"] + rest["support"])  # the decay read once, plus the rest
    assert coulomb.evidence == pytest.approx(coulomb.delta_bic + coulomb.signature_support)
    assert "whole trajectory" in coulomb.interpretation["signature"] and "off the centre" in coulomb.interpretation["signature"]
    assert diag.winner == "coulomb" and signature_confirmed(coulomb)
    record = coulomb.to_dict()
    assert record["signature_support"] == pytest.approx(coulomb.signature_support) and record["evidence"] == pytest.approx(coulomb.evidence)


def test_a_viscous_decay_gives_dry_friction_no_support() -> None:
    chart, _ = _oscillator(1.0, 0.0, 0.08)
    diag = _diagnose(chart)
    env = diag.evidence["envelope"]
    assert env["best"] == "exponential" and env["support"]["linear"] < -10 and env["support"]["hyperbolic"] < -10
    assert diag.evidence["rest"]["support"] < 3  # it comes to rest at its centre
    coulomb = next(f for f in diag.ranking if f.effect == "coulomb")
    assert not signature_confirmed(coulomb) and coulomb.signature_support < 3
    assert diag.winner == "none"


def _fit(effect: str, delta_bic: float, cv_gain: float, support: float, r2: float = 0.3) -> CandidateFit:
    return CandidateFit(effect, {}, np.ones(1), ["c"], np.ones(1), np.full(1, 0.1), 1.0, 1, 0.0, delta_bic=delta_bic, r2=r2,
                        cv_gain=cv_gain, signature_support=support)  # fmt: skip


def test_decide_adds_the_signature_to_the_evidence_and_a_confirmed_one_replaces_the_cv_gain() -> None:
    rule = {"min_delta_bic": 10.0, "min_r2": 0.1, "min_cv_gain": 0.02}
    assert decide([_fit("coulomb", 6.0, 0.3, 5.0)], **rule) is not None  # 6 + 5 >= 10
    assert decide([_fit("coulomb", 6.0, 0.3, 3.0)], **rule) is None
    # a single short block of cross-validation (no gain) is enough when the signature alone is very strong
    assert decide([_fit("coulomb", 12.0, 0.0, 12.0)], **rule) is not None
    assert decide([_fit("coulomb", 12.0, float("nan"), 12.0)], **rule) is not None  # too short for two folds
    assert decide([_fit("coulomb", 12.0, 0.0, 9.0)], **rule) is None
    assert decide([_fit("coulomb", 12.0, -0.1, 30.0)], **rule) is None  # out of sample it loses: not significant
    assert decide([_fit("coulomb", 30.0, 0.5, 30.0, r2=0.05)], **rule) is None  # R2 still applies


def test_on_one_steady_decay_a_drift_goes_behind_a_law_of_the_state_it_cannot_be_told_from() -> None:
    from lagsplat.diagnose.select import state_laws_first

    rule = {"min_delta_bic": 10.0, "min_r2": 0.1, "min_cv_gain": 0.02}

    def ranked() -> list[CandidateFit]:  # drift 1.2 ahead of dry friction, a periodic force far behind
        return [_fit("drift", 22.6, 0.7, 5.5), _fit("coulomb", 20.8, 0.7, 6.1), _fit("periodic_force", 9.8, 0.07, 0.0)]

    one_take = state_laws_first(ranked(), {"corr_amp2_time": -0.99})
    assert [f.effect for f in one_take] == ["coulomb", "drift", "periodic_force"]
    assert decide(one_take, **rule).effect == "coulomb" and one_take[1].interpretation["behind"].startswith("coulomb: one steady decay")
    # takes released at other amplitudes, or too few periods to read: the evidence's order stands
    for frequency in ({"corr_amp2_time": -0.4}, {}):
        assert [f.effect for f in state_laws_first(ranked(), frequency)] == ["drift", "coulomb", "periodic_force"]
    # a drift clearly ahead keeps its place; a periodic force is no trend in time and is never moved
    ahead = [_fit("drift", 30.0, 0.7, 5.5), _fit("coulomb", 20.8, 0.7, 6.1)]
    assert [f.effect for f in state_laws_first(ahead, {"corr_amp2_time": -0.99})] == ["drift", "coulomb"]
    periodic = [_fit("periodic_force", 21.0, 0.7, 0.0), _fit("coulomb", 20.8, 0.7, 0.0)]
    assert [f.effect for f in state_laws_first(periodic, {"corr_amp2_time": -0.99})] == ["periodic_force", "coulomb"]


def test_a_signature_confirmed_winner_is_not_overruled_by_a_rival_refit() -> None:
    """The refit choice would refit both and could take the rival; a confirmed winner is kept without a refit."""
    winner, rival = _fit("coulomb", 21.5, 0.4, 25.0), _fit("periodic_force", 18.0, 0.5, 0.0)
    winner.significant = rival.significant = True
    diag = Diagnosis("coulomb", [winner], [winner, rival], {}, {}, {}, {"min_delta_bic": 10.0})
    out, rows, result = choose_by_refit(None, None, None, diag, baseline_nrmse=0.1)
    assert out is diag and rows == [] and result is None


def test_the_report_leads_with_what_tells_the_candidates_apart() -> None:
    from lagsplat.diagnose.reading import distinguishing_lines, indistinguishable

    chart, _ = _oscillator(1.05, 0.035, 0.005)
    lines = distinguishing_lines(_diagnose(chart).to_dict())
    assert lines[0].startswith("- decay shape: linear (dry friction), evidence")
    assert any(s.startswith("- rest: the motion stops at t = ") and "off the centre" in s for s in lines)
    assert any(s.startswith("- residual spectrum: ") for s in lines) and any("frequency" in s for s in lines)
    # three periods of a viscous decay: the envelope cannot tell the forms apart, and says so
    short, _ = _oscillator(1.0, 0.0, 0.03, duration_s=3.75)
    lines = distinguishing_lines(_diagnose(short).to_dict())
    assert "turning points cannot tell a linear (dry friction), a hyperbolic (quadratic drag) and an exponential" in lines[0]
    assert any("too few to read it against amplitude and time" in s for s in lines)
    rank = [{"effect": "quadratic_drag", "delta_bic": 12.0, "physical": True}, {"effect": "coulomb", "delta_bic": 10.5, "physical": True},
            {"effect": "drift", "delta_bic": 11.0, "physical": False}, {"effect": "end_stop", "delta_bic": 3.0, "physical": True}]  # fmt: skip
    assert indistinguishable(rank) == ["quadratic_drag", "coulomb"]
    assert indistinguishable(rank, min_evidence=20.0) == [] and indistinguishable(rank[:1]) == []


def _drifting(alpha: float = 0.0, zeta: tuple[float, float] = (0.01, 0.01), eps: float = 0.0, duration_s: float = 12.0) -> Chart:
    """``x'' = -w^2 (1 + alpha (t / T - 1/2)) x - eps w^2 x^3 - 2 zeta(t) w x'``, ``zeta`` linear from ``zeta[0]`` to ``zeta[1]``
    over the clip (0.7 Hz, released from 1); a 1-D chart of it with 1 % noise."""
    from scipy.integrate import solve_ivp

    w, T = 2 * math.pi * 0.7, duration_s

    def rhs(t, y):
        z = zeta[0] + (zeta[1] - zeta[0]) * t / T
        return [y[1], -w * w * (1 + alpha * (t / T - 0.5)) * y[0] - eps * w * w * y[0] ** 3 - 2 * z * w * y[1]]

    t = np.arange(int(round(T / DT))) * DT
    x = solve_ivp(rhs, (0, t[-1]), [1.0, 0.0], t_eval=t, rtol=1e-9, atol=1e-11, method="DOP853").y[0]
    q = x / x.std() + 0.01 * np.random.default_rng(1).standard_normal(len(x))
    return _chart(q[:, None], t)


def test_a_drifting_stiffness_shows_in_the_timing_and_a_drifting_damping_in_the_envelope() -> None:
    from lagsplat.diagnose.effects import get_effect

    stiff = _diagnose(_drifting(alpha=0.25))
    f = stiff.evidence["frequency"]
    assert f["support_time"] >= 10 and f["relative_change_over_span"] == pytest.approx(0.25 / 2 * 11 / 12, rel=0.35)
    assert stiff.winner == "drift" and "frequency changes by +" in get_effect("drift").signature_support(stiff.evidence)[1]
    damp = _diagnose(_drifting(zeta=(0.003, 0.03)))
    acc = damp.evidence["envelope"]["accelerating"]
    assert damp.evidence["envelope"]["support"]["accelerating"] >= 10 and acc["rate_change_per_s2"] > 0
    assert damp.winner == "drift"


def test_a_constant_oscillator_and_a_duffing_spring_give_a_drift_no_support() -> None:
    from lagsplat.diagnose.effects import get_effect

    for chart in (_drifting(), _drifting(eps=0.3, zeta=(0.04, 0.04))):  # viscous; hardening with a fast decay
        diag = _diagnose(chart)
        assert diag.evidence["frequency"]["support_time"] < 6 and diag.evidence["envelope"]["support"]["accelerating"] < 6
        assert get_effect("drift").signature_support(diag.evidence)[0] < 6 and diag.winner != "drift"


def test_a_lightly_damped_hardening_spring_is_read_by_its_amplitude_not_as_a_drift() -> None:
    # the amplitude decays slowly and steadily, so time and amplitude are nearly collinear: the periods
    # that start on a rising and on a falling crossing differ a little, and a per-period amplitude that
    # steps in pairs let a time trend take that difference for a drift (support 19 before the fix)
    diag = _diagnose(_drifting(eps=0.3, zeta=(0.006, 0.006)))
    f = diag.evidence["frequency"]
    assert f["support_time"] < 6 and f["relative_shift_at_max_amplitude"] > 0.03
    assert diag.winner != "drift"


def test_two_beating_modes_give_a_drift_no_support_from_the_timing() -> None:
    # a 2-D chart of two light, constant modes (0.7 and 0.95 Hz): along any one direction the crossings come
    # early or late with the modes' relative phase, which is not a stiffness that drifts
    t = np.arange(int(round(12.0 / DT))) * DT
    m1 = np.exp(-0.02 * t) * np.cos(2 * math.pi * 0.7 * t)
    m2 = 0.35 * np.exp(-0.02 * t) * np.cos(2 * math.pi * 0.95 * t + 0.4)
    q = np.stack([m1 + m2, 0.6 * m1 - m2], 1) + 0.005 * np.random.default_rng(3).standard_normal((len(t), 2))
    ev = _diagnose(_chart(q, t, G_bar=np.diag([1.0, 0.3]))).evidence["frequency"]
    assert ev["n_periods"] >= 8 and ev["support_time"] == 0.0


def _takes(n_takes: int = 3, take_s: float = 8.0, zeta: tuple[float, float] = (0.003, 0.03)) -> Chart:
    """Separate takes of one oscillator (0.7 Hz, each released at a random phase) whose damping ratio rises
    linearly with the recording's clock from ``zeta[0]`` to ``zeta[1]``; a 1-D chart, 1 % noise, one episode per take."""
    from scipy.integrate import solve_ivp

    w, T = 2 * math.pi * 0.7, n_takes * take_s
    rng = np.random.default_rng(0)
    qs, ts, eps = [], [], []
    for k in range(n_takes):
        t = k * take_s + np.arange(int(round(take_s / DT))) * DT
        ph = rng.uniform(0, 2 * math.pi)
        rhs = lambda tt, y: [y[1], -w * w * y[0] - 2 * (zeta[0] + (zeta[1] - zeta[0]) * tt / T) * w * y[1]]  # noqa: E731
        qs.append(solve_ivp(rhs, (t[0], t[-1]), [math.cos(ph), -w * math.sin(ph)], t_eval=t, rtol=1e-9, atol=1e-11).y[0])
        ts.append(t)
        eps.append(np.full(len(t), k, np.int16))
    q = np.concatenate(qs)
    q = q / q.std() + 0.01 * rng.standard_normal(len(q))
    return _chart(q[:, None], np.concatenate(ts), episode=np.concatenate(eps))


def test_a_drifting_damping_is_read_on_the_recording_clock_across_takes() -> None:
    # the decay rate of each take starts where the previous take left off: on each take's own clock the three
    # takes' rates disagree and the envelope looked linear (dry friction) instead
    diag = _diagnose(_takes())
    env = diag.evidence["envelope"]
    assert diag.settings["n_segments"] == 3
    assert env["support"]["accelerating"] >= 10 and env["accelerating"]["rate_change_per_s2"] > 0
    assert env["support"]["accelerating"] > env["support"]["linear"]
    assert diag.winner == "drift"


def test_on_one_decaying_take_the_report_says_whether_the_timing_tells_a_drifting_stiffness_from_an_amplitude_dependent_one() -> None:
    from lagsplat.diagnose.reading import distinguishing_lines

    def amplitude_and_time(chart: Chart) -> tuple[dict, list[str]]:
        dg = _diagnose(chart).to_dict()
        return dg["evidence"]["frequency"], [s for s in distinguishing_lines(dg) if s.startswith("- amplitude and time: ")]

    # a hardening spring decaying steadily: A^2 and t are one variable, and the timing cannot separate them
    fr, lines = amplitude_and_time(_drifting(eps=0.3, zeta=(0.006, 0.006)))
    assert fr["corr_amp2_time"] < -0.9 and len(lines) == 1 and "cannot be told apart here" in lines[0]
    # a stiffness drift of 25 % over the clip: the timing changes at a given amplitude, and says so
    fr, lines = amplitude_and_time(_drifting(alpha=0.25))
    assert fr["corr_amp2_time"] < -0.9 and fr["support_time"] >= 10 and len(lines) == 1 and "the timing still separates them" in lines[0]
    # separate takes released at other amplitudes: amplitude and time are not one variable, no such line
    fr, lines = amplitude_and_time(_takes())
    assert abs(fr["corr_amp2_time"]) < 0.9 and lines == []


def _quintic(e5: float, zeta: float, seed: int = 1) -> Chart:
    """``x'' = -w^2 x (1 + e5 x^4) - 2 zeta w x'`` (0.7 Hz, released from 1, 12 s); a 1-D chart of it with 1 % noise."""
    from scipy.integrate import solve_ivp

    w = 2 * math.pi * 0.7
    t = np.arange(int(round(12.0 / DT))) * DT
    x = solve_ivp(lambda _, y: [y[1], -w * w * y[0] * (1 + e5 * y[0] ** 4) - 2 * zeta * w * y[1]], (0, t[-1]), [1.0, 0.0],
                  t_eval=t, rtol=1e-9, atol=1e-11, method="DOP853").y[0]  # fmt: skip
    q = x / x.std() + 0.01 * np.random.default_rng(seed).standard_normal(len(x))
    return _chart(q[:, None], t)


def test_a_stiffness_that_a_cubic_cannot_follow_is_not_read_as_a_drift() -> None:
    # a quintic spring on one decaying take: the stiffness falls with the amplitude in a way a cubic correction
    # does not follow, and with only cubic nuisance terms the rest fitted as a drift (Delta BIC 52, significant)
    for e5 in (0.4, -0.3):
        diag = _diagnose(_quintic(e5, 0.02))
        assert diag.winner == "cubic_stiffness"
        assert not any(f.significant for f in diag.ranking if f.effect == "drift")


def test_a_drift_whose_stiffness_change_the_periods_contradict_is_not_practical() -> None:
    from lagsplat.diagnose.effects import get_effect

    drift = get_effect("drift")
    th = {"min_cubic_shift": 0.03}
    chk = {"predicted_rel_per_s": 0.012, "measured_rel_per_s": 0.001, "measured_se_rel_per_s": 0.001, "span_s": 8.0}
    ok, why = drift.practical({"timing_check": chk}, th)  # +9.6 % predicted, +0.8 +- 0.8 % recorded
    assert not ok and "predicts +9.6 %" in why and "misfit" in why
    assert drift.practical({"timing_check": {**chk, "measured_rel_per_s": 0.008}}, th)[0]  # the periods show it
    assert drift.practical({"timing_check": {**chk, "measured_se_rel_per_s": 0.004}}, th)[0]  # within 3 s.e.
    assert drift.practical({"timing_check": {**chk, "predicted_rel_per_s": 0.0015}}, th)[0]  # a stiffness change too small to check
    assert drift.practical({"timing_check": None}, th)[0] and drift.practical({}, th)[0]


def test_a_drift_that_takes_the_stiffness_or_the_damping_through_zero_is_not_practical() -> None:
    from lagsplat.diagnose.effects import get_effect

    drift = get_effect("drift")
    th = {"min_cubic_shift": 0.03}
    # a double pendulum without any effect, three periods, d = 2 (no timing check): -1093 % stiffness, +4985 % damping
    absurd = {"dk_dt": -1634.0, "dk_dt_se": 447.0, "dc_dt": 154.0, "dc_dt_se": 37.8, "k_model": 468.5, "c_model": 9.69, "span_s": 3.13}
    ok, why = drift.practical(absurd, th)
    assert not ok and "through zero" in why and "stiffness" in why
    ok, why = drift.practical({**absurd, "dk_dt": -100.0}, th)  # the stiffness stays positive; the damping does not
    assert not ok and "damping" in why
    # a damping that rises from near zero to nearly twice its mean (a blind cart, +186 % over the clip) is a drift
    rising = {"dk_dt": 0.0, "dk_dt_se": 0.1, "dc_dt": 0.0465, "dc_dt_se": 0.002, "k_model": 25.0, "c_model": 0.5, "span_s": 20.0}
    assert drift.practical(rising, th)[0]
    # past zero by less than two standard errors of the rate: not ruled out
    assert drift.practical({**rising, "dc_dt": 0.055, "dc_dt_se": 0.004}, th)[0]
    assert not drift.practical({**rising, "dc_dt": 0.07, "dc_dt_se": 0.004}, th)[0]


def test_a_signature_confirmed_candidate_is_judged_by_its_own_cross_validation() -> None:
    from lagsplat.diagnose.diagnosis import failed_rules

    rule = (10.0, 0.1, 0.02)
    # the realistic pendulum with dry friction: decay-law support 41, CV gain -0.25 with the quintic refitted per fold
    assert failed_rules(True, True, 62.7, 0.59, -0.25, 41.0, *rule, cv_gain_own=0.69) == []
    assert failed_rules(True, True, 62.7, 0.59, -0.25, 41.0, *rule, cv_gain_own=-0.05) == ["cv_gain"]
    assert failed_rules(True, True, 62.7, 0.59, -0.25, 41.0, *rule) == ["cv_gain"]  # not computed: the plain gain
    assert failed_rules(True, True, 62.7, 0.59, -0.25, 5.0, *rule, cv_gain_own=0.69) == ["cv_gain"]  # no strong signature


def test_the_own_cross_validation_holds_the_in_class_corrections_at_their_whole_take_fit() -> None:
    from lagsplat.diagnose.regression import Regression, blocked_folds, linear_features, poly_features

    chart, _ = _oscillator(1.0, 0.01, 0.01)
    res = diagnose_chart(fit_linear_oscillator([chart.q], DT), chart)[1]
    rng = np.random.default_rng(5)
    folds = blocked_folds(res, 5, None)
    P = poly_features(res, ("potential", "inertia"))
    v = res.qdot[:, 0]
    friction = np.tanh(v / (0.05 * np.abs(v).max()))[:, None]
    # a target that is a large in-class polynomial, a constant dry friction and white noise (noise units)
    curve = (P / np.maximum(P.std(0), 1e-12)) @ rng.normal(0.0, 1.0, P.shape[1])
    target = (curve[:, None] + 3.0 * friction + rng.standard_normal((res.n, 1))) * res.noise_r[None]
    reg = Regression(res, folds, target, linear_features(res), ("potential", "inertia"))
    design = reg.stack(friction, np.ones(1))
    w, ssr, _ = reg.fit(design, True)
    r2 = 1.0 - ssr / float(reg.r0 @ reg.r0)
    own = 1.0 - reg.cv_sse_own(design, True) / reg.cv_sse_own(None, False)
    assert w[0] > 0 and r2 > 0.5
    assert abs(own - r2) < 0.1  # one constant coefficient: what it explains in sample it predicts on held-back blocks
    # without folds to hold back there is no cross-validation at all
    assert math.isnan(Regression(res, np.zeros(res.n, int), target, linear_features(res), ("potential",)).cv_sse_own(design, True))


def test_a_force_that_beats_with_the_oscillation_slower_than_the_record_is_not_sought() -> None:
    from types import SimpleNamespace

    from lagsplat.diagnose.spectrum import frequency_allowed

    dt = 1 / 30

    def res(seconds: float) -> SimpleNamespace:
        return SimpleNamespace(meta={"model_freqs_hz": [0.8]}, f_dominant_hz=0.78, dt=dt, n_u=0, states=[SimpleNamespace(t=np.arange(int(seconds / dt)) * dt)])

    assert not frequency_allowed(res(9.4), 0.671)  # 0.86x: fewer than 1.5 beats in 9.4 s
    assert frequency_allowed(res(40.0), 0.671)  # 4.4 beats in 40 s
    assert frequency_allowed(res(9.4), 0.39)  # 0.5x: where the realistic suite's slow forces lie


def test_a_hidden_mode_too_small_to_move_the_object_is_not_a_finding() -> None:
    # a plain viscous oscillator with 1 % chart noise: this noise draw fits a "mode" at 2.3x the oscillation with
    # Delta BIC 11, whose motion is 0.2 % of the recorded one
    from scipy.integrate import solve_ivp

    w = 2 * math.pi * 0.7
    t = np.arange(int(round(12.0 / DT))) * DT
    x = solve_ivp(lambda _, y: [y[1], -w * w * y[0] - 0.02 * w * y[1]], (0, t[-1]), [1.0, 0.0], t_eval=t, rtol=1e-9, atol=1e-11).y[0]
    q = x / x.std() + 0.01 * np.random.default_rng(1).standard_normal(len(x))
    diag = _diagnose(_chart(q[:, None], t))
    mode = next(f for f in diag.ranking if f.effect == "missing_dof")
    assert mode.interpretation["driven_over_motion"] < 0.01 and not mode.practical
    assert "too small to change what the video shows" in mode.interpretation["below_practical_size"]
    assert diag.winner == "none"


def test_a_residual_at_the_motions_own_frequency_is_not_read_as_a_force_the_model_lacks() -> None:
    """A nonlinear model's mode at rest can sit well off the frequency it moves at (a learned potential: 0.74 Hz at
    rest, 0.62 Hz on the clip); a stiffness misfit then leaves a residual at the motion's frequency, which the
    evidence must not list among the peaks the model lacks (where a periodic force or hidden mode is sought)."""
    chart, _ = _oscillator(1.0, 0.0, 0.005, f_hz=0.62)
    stiffer, _ = _oscillator(1.0, 0.0, 0.005, f_hz=0.66)
    model = fit_linear_oscillator([stiffer.q[s] for s in stiffer.segments(TRAIN)], DT)  # 13 % too stiff for this clip
    spec = diagnose_chart(model, chart, model_freqs_hz=[0.74])[0].evidence["spectrum"]
    assert any(abs(f - 0.62) < 0.03 for f in spec["residual_peaks_hz"])  # the misfit shows at the motion's frequency
    assert [round(f, 2) for f in spec["model_freqs_hz"]] == [0.62, 0.74]  # the model's mode and the motion's frequency
    assert not any(abs(f - 0.62) < 0.03 for f in spec["unexplained_peaks_hz"])


def test_a_frequency_trend_between_weak_and_strong_is_reported_as_not_conclusive_not_as_none() -> None:
    from lagsplat.diagnose.reading import distinguishing_lines

    def line(z_amp2: float, z_time: float) -> str:
        fr = {"z_amp2": z_amp2, "z_time": z_time, "relative_shift_at_max_amplitude": -0.06, "relative_change_over_span": -0.02,
              "corr_amp2_time": -0.5, "support_time": 0.0}  # fmt: skip
        return next(s for s in distinguishing_lines({"evidence": {"frequency": fr}}) if s.startswith("- frequency"))

    # a realistic spring cart whose stiffness drifts 6.6 % over the training frames: periods -2 % at z = -2.4
    assert "a weak trend in time (-2.0 % over the recording, z = -2.4: not conclusive)" in line(-0.7, -2.4)
    assert "frequency independent of the amplitude (z = -0.7)" in line(-0.7, -2.4)
    assert "no drift in time (z = -1.2)" in line(-0.7, -1.2)
    assert "it drifts over the recording (-2.0 %, z = -4.0)" in line(-0.7, -4.0)
    assert "falls a little with the amplitude (-6.0 % at the largest, z = -2.5: not conclusive)" in line(-2.5, 0.0)


def test_the_report_says_which_rule_stops_strong_evidence_from_being_a_finding() -> None:
    from lagsplat.diagnose.reading import not_significant_lines

    st = {"min_delta_bic": 10.0, "min_r2": 0.1, "min_cv_gain": 0.02}
    small = {"effect": "cubic_stiffness", "evidence": 469.6, "delta_bic": 469.6, "r2": 0.85, "cv_gain": 0.84, "physical": True, "practical": False,
             "significant": False, "interpretation": {"below_practical_size": "frequency shift 2.9 % at the largest amplitude, below 3 %"}}  # fmt: skip
    no_cv = {"effect": "missing_dof", "evidence": 15.8, "delta_bic": 15.8, "r2": 0.3, "cv_gain": -2.9, "physical": True, "practical": True,
             "significant": False, "signature_support": 0.0}  # fmt: skip
    weak = {"effect": "coulomb", "evidence": 7.9, "delta_bic": 7.9, "r2": 0.5, "cv_gain": 0.3, "physical": True, "practical": True, "significant": False}
    won = {**small, "effect": "end_stop", "practical": True, "significant": True}
    lines = not_significant_lines({"settings": st, "ranking": [won, small, no_cv, weak]})
    assert lines == ["- cubic_stiffness (evidence 469.6): set aside by its physical check: frequency shift 2.9 % at the largest amplitude, below 3 %",
                     "- missing_dof (evidence 15.8): it does not predict held-back blocks of the training frames (CV gain -2.90, needs 0.02)"]  # fmt: skip
    # the envelope's or rest's own evidence stands in for the CV gain (as the selection rule reads it)
    assert not_significant_lines({"settings": st, "ranking": [{**no_cv, "cv_gain": 0.0, "signature_support": 12.0}]}) == []
    assert "R2 needs 0.1" in not_significant_lines({"settings": st, "ranking": [{**no_cv, "r2": 0.05, "cv_gain": 0.5}]})[0]


def test_a_nonlinearity_the_identified_model_already_carries_is_named_under_nothing_significant() -> None:
    from lagsplat.diagnose.reading import carried_nonlinearity_line

    def dg(shift: float = 0.059, z: float = 52.7, excess: float = 0.654, corr: float = -0.5, support_time: float = 0.0) -> dict:
        fr = {"z_amp2": z, "relative_shift_at_max_amplitude": shift, "corr_amp2_time": corr, "support_time": support_time}
        return {"evidence": {"frequency": fr}, "null": {"excess_over_noise": excess}, "settings": {"min_cubic_shift": 0.03, "min_delta_bic": 10.0}}

    # blind suite, cart with a hardening spring that the learned potential absorbed (verdict "nothing significant")
    line = carried_nonlinearity_line(dg())
    assert line.startswith("the recorded frequency rises with the amplitude (+5.9 % at the largest, z = 52.7): a hardening restoring force")
    assert "already carries" in line and "drifting" not in line
    assert "softening" in carried_nonlinearity_line(dg(shift=-0.08, z=-90.0))
    assert carried_nonlinearity_line(dg(shift=0.006, z=-18.0)) == ""  # a pendulum's -0.6 %: below the practical size
    assert carried_nonlinearity_line(dg(z=2.0)) == ""  # not strong evidence
    assert carried_nonlinearity_line(dg(excess=5.0)) == ""  # the model does not reproduce the clip: not "carried"
    assert "drifting in time would change the periods alike" in carried_nonlinearity_line(dg(corr=-0.97, support_time=3.0))
    assert "drifting" not in carried_nonlinearity_line(dg(corr=-0.97, support_time=15.0))  # the timing separates them


def test_a_stop_turns_the_motion_around_sharply_on_one_side_and_a_cubic_alike_on_both() -> None:
    from test_diagnose import _bilinear_spring_chart, _chart, _linear

    stop = _bilinear_spring_chart(20.0, 0.6)  # 20x stiffer past x = 0.6 of the release amplitude
    diag, _ = diagnose_chart(_linear(stop), stop, candidates=["cubic_stiffness"])
    turn = diag.evidence["turning"]
    assert turn["sharper_side"] == "upper" and turn["ratio"] > 2 and turn["support"] > 10 and min(turn["n_upper"], turn["n_lower"]) >= 8
    cubic = _chart("cart", "cubic_stiffness", 0)
    diag, _ = diagnose_chart(_linear(cubic), cubic, candidates=["cubic_stiffness"])
    assert diag.evidence["turning"]["ratio"] < 1.2 and diag.evidence["turning"]["support"] < 0
    assert diag.winner == "cubic_stiffness"


def test_a_cubic_is_not_claimed_where_one_side_turns_far_sharper() -> None:
    # three periods of a cart against a stop: too few periods to check a cubic's timing, so only its shape tells
    from test_diagnose import _chart, _first_periods, _linear

    stop = _first_periods(_chart("cart", "end_stop", 0), 3.0)
    loose, _ = diagnose_chart(_linear(stop), stop, candidates=["cubic_stiffness"], min_one_sided_turning=1e9)
    assert loose.ranking[0].practical  # without the shape rule the cubic would stand
    diag, _ = diagnose_chart(_linear(stop), stop, candidates=["cubic_stiffness"])
    cubic = diag.ranking[0]
    assert not cubic.practical and "as sharply on the upper side" in cubic.interpretation["below_practical_size"]
    genuine = _first_periods(_chart("cart", "cubic_stiffness", 1), 3.0)  # a softening spring over three periods keeps its claim
    diag, _ = diagnose_chart(_linear(genuine), genuine, candidates=["cubic_stiffness"])
    assert diag.winner == "cubic_stiffness"
    assert diagnose_chart(_linear(stop), stop, candidates=["cubic_stiffness"], min_one_sided_turning=1e9)[0].settings["min_one_sided_turning"] == 1e9


def test_the_sharp_turns_on_a_stops_side_support_the_stop_on_either_chart_orientation() -> None:
    import dataclasses

    from test_diagnose import _chart, _first_periods, _linear

    stop = _first_periods(_chart("cart", "end_stop", 0), 3.0)
    mirrored = dataclasses.replace(stop, q=-stop.q)  # the same motion read through a chart of the opposite sign
    supports = []
    for ch in (stop, mirrored):
        diag, _ = diagnose_chart(_linear(ch), ch, candidates=["end_stop"])
        fit = diag.ranking[0]
        struck = fit.interpretation.get("impacts")  # a stiff stop reverses the motion at speed: read as impacts first
        expected = struck["evidence"] if struck else diag.evidence["turning"]["support"]
        assert fit.signature_support == pytest.approx(expected) and expected > 10
        assert ("struck on" if struck else "as sharply on the stop's side") in fit.interpretation["text"]
        supports.append(fit.signature_support)
    assert supports[0] == pytest.approx(supports[1], rel=1e-6)  # the same on either orientation
    diag, _ = diagnose_chart(_linear(stop), stop, candidates=["end_stop"], min_one_sided_turning=1e9)
    struck = diag.ranking[0].interpretation.get("impacts")
    assert diag.ranking[0].signature_support == (struck["evidence"] if struck else 0.0)  # the turning rule off: impacts only
