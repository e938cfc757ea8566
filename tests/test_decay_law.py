"""The whole trajectory's decay law (lagsplat.diagnose.decay_law) on oscillators with a known dissipation."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from lagsplat.diagnose.decay_law import MIN_LOSS_PER_PERIOD, decay_law, law_evidence
from lagsplat.diagnose.effects import get_effect

F_HZ, FPS, SECONDS, NOISE = 0.8, 30.0, 8.0, 0.004


def _free_decay(accel, x0: float, seconds: float) -> tuple[np.ndarray, np.ndarray]:
    """Times and positions at ``FPS`` of ``x'' = accel(x, x')`` released at rest from ``x0``."""
    t = np.arange(int(seconds * FPS)) / FPS
    x = solve_ivp(lambda _t, y: [y[1], accel(y[0], y[1])], (0, t[-1]), [x0, 0.0], t_eval=t, method="LSODA", rtol=1e-9, atol=1e-11,
                  max_step=0.01).y[0]  # fmt: skip
    return t, x


def _record(t: np.ndarray, q: np.ndarray, segments: list[np.ndarray], u: np.ndarray | None = None) -> SimpleNamespace:
    """What :func:`decay_law` reads of a residual: ``q [n, d]`` at ``t``, the segments' sample indices and the input."""
    u = np.zeros((len(t), 0)) if u is None else u
    return SimpleNamespace(d=q.shape[1], u=u, q_raw=q, t=t, f_dominant_hz=F_HZ, states=[], segment_slices=lambda: segments)


def _res(law: str, seed: int = 0, d: int = 1, actuated: bool = False, seconds: float = SECONDS) -> SimpleNamespace:
    """One free decay (amplitude 1) of a 0.8 Hz oscillator with viscous damping plus ``law``, seen with white noise."""
    w = 2 * math.pi * F_HZ

    def accel(x, v):
        a = -w * w * x - 2 * 0.01 * w * v
        if law == "dry":
            a -= 0.015 * w * w * math.tanh(v / (0.01 * w))
        elif law == "drag":
            a -= 0.25 * abs(v) * v
        return a

    t, x = _free_decay(accel, 1.0, seconds)
    x = x + np.random.default_rng(seed).normal(0.0, NOISE, x.shape)
    q = np.column_stack([x] + [0.1 * x] * (d - 1))
    return _record(t, q, [np.arange(len(t))], np.column_stack([np.sin(t)]) if actuated else None)


def test_dry_friction_reads_dry_and_not_drag():
    out = decay_law(_res("dry"), np.ones(1))
    assert out["dry"]["sign_ok"] and out["dry"]["evidence"] > 10
    assert not (out["drag"]["sign_ok"] and out["drag"]["evidence"] > 0)
    # mu = 0.015 w^2 on an amplitude of 1 takes 4 mu / w^2 = 6 % of it per period
    assert out["dry"]["loss_per_period"] == pytest.approx(0.06, rel=0.25) and out["dry"]["practical"]


def test_quadratic_drag_reads_drag_and_not_dry():
    out = decay_law(_res("drag"), np.ones(1))
    assert out["drag"]["sign_ok"] and out["drag"]["evidence"] > 10
    assert not (out["dry"]["sign_ok"] and out["dry"]["evidence"] > 0)


@pytest.mark.parametrize("seed", [0, 1])
def test_viscous_decay_reads_no_law(seed):
    out = decay_law(_res("viscous", seed), np.ones(1))
    assert out["n"] == int(SECONDS * FPS)
    for law in ("dry", "drag"):
        assert not (out[law]["sign_ok"] and out[law]["evidence"] >= 10), out


def test_not_read_with_an_input_or_two_dimensions():
    assert decay_law(_res("dry", actuated=True), np.ones(1)) == {}
    assert decay_law(_res("dry", d=2), np.array([1.0, 0.0])) == {}


def test_too_short_a_segment_is_not_read():
    res = _res("dry")
    res.f_dominant_hz = 0.2  # 8 s are 1.6 periods
    assert decay_law(res, np.ones(1)) == {}


@pytest.mark.parametrize("law", ["dry", "drag", "viscous"])
def test_a_training_part_of_three_periods_is_read(law):
    # a clip cut to three periods of training frames leaves a segment a little shorter than three periods
    out = decay_law(_res(law, seconds=2.9 / F_HZ), np.ones(1))
    assert out["n"] == int(2.9 / F_HZ * FPS)
    for other in ("dry", "drag"):
        if other == law:
            assert out[law]["sign_ok"] and out[law]["evidence"] > 10, out
        else:
            assert not (out[other]["sign_ok"] and out[other]["evidence"] >= 10), out


def test_the_candidates_take_the_sharper_reading_of_the_decay():
    law = {"dry": {"evidence": 25.0, "coef": 0.4, "sign_ok": True}, "drag": {"evidence": 24.0, "coef": -0.01, "sign_ok": False}}
    ev = {"envelope": {"support": {"linear": 3.0, "hyperbolic": 0.0}}, "rest": {"support": 0.0}, "decay_law": law}
    sup, text = get_effect("coulomb").signature_support(ev)
    assert sup == pytest.approx(25.0) and "whole trajectory" in text
    sup, text = get_effect("quadratic_drag").signature_support(ev)
    assert sup == 0.0 and text == ""  # its coefficient took the sign of dry friction
    ev["envelope"]["support"]["linear"] = 30.0
    sup, text = get_effect("coulomb").signature_support(ev)
    assert sup == pytest.approx(30.0) and "turning points" in text


def _pendulum_takes(law: str, amplitudes: tuple[float, ...], seed: int = 0) -> SimpleNamespace:
    """Takes of a damped pendulum (``sin`` restoring force) released at ``amplitudes`` (rad), 6 s each, seen through a
    mildly distorting chart ``q = x + 0.1 x^2`` with white noise."""
    w = 2 * math.pi * F_HZ

    def accel(x, v):
        a = -w * w * math.sin(x) - 2 * 0.02 * w * v
        return a - (0.02 * w * w * math.tanh(v / (0.01 * w)) if law == "dry" else 0.0)

    ts, qs = [], []
    for i, a in enumerate(amplitudes):
        t, x = _free_decay(accel, a, 6.0)
        qs.append(x + 0.1 * x**2 + np.random.default_rng(seed).normal(0.0, NOISE, x.shape))
        ts.append(t + 7.0 * i)
    t = np.concatenate(ts)
    return _record(t, np.concatenate(qs)[:, None], np.split(np.arange(len(t)), np.cumsum([len(x) for x in ts])[:-1]))


@pytest.mark.parametrize("seed", [0, 1])
def test_takes_released_at_different_amplitudes_read_no_law_from_the_potential(seed):
    # one base shared by the four takes fits the pendulum's softening only on average and read dry friction
    # at evidence 18 / 15 on these two noise draws; each take's own base leaves nothing to the law
    out = decay_law(_pendulum_takes("viscous", (0.5, 1.0, 1.5, 2.0), seed), np.ones(1))
    for law in ("dry", "drag"):
        assert not (out[law]["sign_ok"] and out[law]["evidence"] > 0), out
    dry = decay_law(_pendulum_takes("dry", (0.5, 1.0, 1.5, 2.0), seed), np.ones(1))
    assert dry["dry"]["sign_ok"] and dry["dry"]["evidence"] > 10, dry


def test_a_law_below_its_practical_size_is_no_evidence():
    # a sign-correct dry-friction reading far above the threshold, but of a law that takes 0.2 % of the amplitude per period
    small = {"evidence": 40.0, "coef": 0.001, "sign_ok": True, "loss_per_period": 0.2 * MIN_LOSS_PER_PERIOD, "practical": False}
    record = {"dry": small, "drag": {"evidence": -3.0, "coef": -0.01, "sign_ok": False, "loss_per_period": -0.01, "practical": False}}
    assert law_evidence(record, "dry") == -math.inf
    assert law_evidence(record, "dry", practical_only=False) == pytest.approx(40.0)
    ev = {"envelope": {"support": {"linear": 3.0, "hyperbolic": 0.0}}, "rest": {"support": 0.0}, "decay_law": record}
    sup, text = get_effect("coulomb").signature_support(ev)
    assert sup == pytest.approx(3.0) and "whole trajectory" not in text  # the turning points' own reading stands
    record["dry"] = {**small, "loss_per_period": 3 * MIN_LOSS_PER_PERIOD, "practical": True}
    assert law_evidence(record, "dry") == pytest.approx(40.0)


def test_a_weak_dry_friction_is_read_but_not_practical():
    # mu = 0.0005 w^2 on an amplitude of 1 (0.2 % of the amplitude per period), a long clip with little noise
    w = 2 * math.pi * F_HZ

    def accel(x, v):
        return -w * w * x - 2 * 0.01 * w * v - 0.0005 * w * w * math.tanh(v / (0.01 * w))

    t, x = _free_decay(accel, 1.0, 20.0)
    x = x + np.random.default_rng(0).normal(0.0, 0.0005, x.shape)
    out = decay_law(_record(t, x[:, None], [np.arange(len(t))]), np.ones(1))
    assert out["dry"]["sign_ok"] and out["dry"]["loss_per_period"] == pytest.approx(0.002, rel=0.5)
    assert not out["dry"]["practical"] and law_evidence(out, "dry") == -math.inf
