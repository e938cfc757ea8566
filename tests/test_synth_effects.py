"""Tests of the synthetic clips with one known unmodelled effect (lagsplat.synth.effects)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter1d

from lagsplat.io.clip import HELD_OUT, TRAIN
from lagsplat.synth import GENERATORS, make_clip
from lagsplat.synth.effect_truth import EFFECTS, MAX_EXCURSION, SYSTEMS, sample_truth
from lagsplat.synth.effects import simulate_effect, true_acceleration
from lagsplat.synth.effect_clips import blind_suite, make_effect_clip

FPS = 240.0  # fine sampling, so that finite differences give the acceleration accurately


def _law(truth: dict, x: np.ndarray, v: np.ndarray, t: np.ndarray, T_clip: float, u_at=None) -> np.ndarray:
    """The documented acceleration law of the 1-DOF effects (module docstring table), written independently."""
    w0 = 2 * math.pi * truth["f0_hz"]
    A, p, z = truth["amplitude"], truth["effect_params"], truth["zeta"]
    g = np.sin(x) if truth["system"] == "pendulum" else x
    k2 = np.full_like(x, w0 * w0)
    zeta = np.full_like(x, z)
    eff = truth["effect"]
    if eff == "drift" and p["kind"] == "stiffness":
        k2 = w0 * w0 * (1 + p["alpha"] * (t / T_clip - 0.5))
    if eff == "drift" and p["kind"] == "damping":
        zeta = p["zeta_start"] + (p["zeta_end"] - p["zeta_start"]) * t / T_clip
    a = -k2 * g - 2 * zeta * w0 * v
    if eff == "coulomb":
        a = a - p["mu"] * np.tanh(v / p["v_s"])
    elif eff == "quadratic_drag":
        a = a - p["c2"] * np.abs(v) * v
    elif eff == "end_stop":
        a = a - p["k_ratio"] * w0 * w0 * np.maximum(p["side"] * (x - p["x_stop"]), 0) * p["side"]
    elif eff == "cubic_stiffness":
        a = a - p["eps"] * w0 * w0 * x**3 / A**2
    elif eff == "periodic_force":
        a = a + p["amplitude"] * np.cos(2 * math.pi * p["f_hz"] * t + p["phase"])
    if u_at is not None:
        a = a + truth["actuation"]["gain"] * u_at(t - p.get("tau_s", 0.0))
    return a


def _logged_input(truth: dict):
    """The documented logged input ``u(t)`` of an actuated clip (module docstring of the library), or ``None``."""
    if not truth["actuated"]:
        return None
    a = truth["actuation"]
    f, amp, ph = (np.asarray(a[k]) for k in ("freqs_hz", "amps", "phases"))
    return lambda tt: amp.sum() + (amp * np.sin(2 * math.pi * f * np.asarray(tt)[:, None] + ph)).sum(-1)


@pytest.mark.parametrize("system", SYSTEMS)
@pytest.mark.parametrize("effect", [e for e in EFFECTS if e != "missing_dof"])
def test_simulated_motion_obeys_the_documented_law(system: str, effect: str) -> None:
    run = simulate_effect(system, effect, seed=1, fps=FPS, duration_s=3.0, n_episodes=2)
    tr = run.truth
    assert run.effect == effect and tr["effect"] == effect and tr["system"] == system
    T_clip = len(run.t) / FPS
    u_at = _logged_input(tr)
    if tr["actuated"]:
        np.testing.assert_allclose(run.u[:, 0], u_at(run.t), rtol=1e-5, atol=1e-5)  # the logged input
        assert run.u.min() >= 0.0
    for e in range(2):
        sl = run.episode == e
        x, v, t = run.x[sl], run.xdot[sl], run.t[sl]
        acc = np.gradient(v, 1 / FPS)
        law = _law(tr, x, v, t, T_clip, u_at)
        inner = slice(3, -3)
        scale = (2 * math.pi * tr["f0_hz"]) ** 2 * tr["amplitude"]
        tol = 0.05 if effect in ("end_stop", "coulomb") else 0.01  # a switch is sharp for a 3-point derivative
        err = np.abs(acc - law)[inner]
        assert np.median(err) < 0.2 * tol * scale
        assert np.quantile(err, 0.98) < tol * scale * (10 if effect in ("end_stop", "coulomb") else 1)
        np.testing.assert_allclose(np.gradient(x, 1 / FPS)[inner], v[inner], rtol=0, atol=2e-3 * (2 * math.pi * tr["f0_hz"]) * tr["amplitude"])


@pytest.mark.parametrize("system", SYSTEMS)
@pytest.mark.parametrize("effect", [e for e in EFFECTS if e != "missing_dof"])
def test_the_exported_law_is_the_documented_one_on_any_state(system: str, effect: str) -> None:
    run = simulate_effect(system, effect, seed=2, fps=30.0, duration_s=4.0, n_episodes=2)
    tr = run.truth
    T_clip = len(run.t) / 30.0
    rng = np.random.default_rng(0)
    A, w0 = tr["amplitude"], 2 * math.pi * tr["f0_hz"]
    x, v, t = rng.uniform(-1.3 * A, 1.3 * A, 200), rng.uniform(-1.3 * w0 * A, 1.3 * w0 * A, 200), rng.uniform(0, T_clip, 200)
    u_at = _logged_input(tr)
    np.testing.assert_allclose(true_acceleration(tr, T_clip)(t, x, v), _law(tr, x, v, t, T_clip, u_at), rtol=1e-12, atol=1e-12 * w0 * w0 * A)
    assert np.isscalar(float(true_acceleration(tr, T_clip)(0.5, 0.1 * A, 0.0)))  # one state, as the integrator calls it
    with pytest.raises(ValueError, match="two degrees of freedom"):
        true_acceleration({**tr, "effect": "missing_dof"}, T_clip)


def test_effects_leave_their_signature() -> None:
    # Coulomb: turning-point amplitudes fall on a line (dry friction) rather than an exponential
    run = simulate_effect("cart", "coulomb", seed=0, duration_s=15.0)
    x = run.x[run.episode == 0]
    i = np.flatnonzero((x[1:-1] > x[:-2]) & (x[1:-1] >= x[2:])) + 1
    amp = x[i]
    t = i / 30.0
    lin = np.polyfit(t, amp, 1)
    ex = np.polyfit(t, np.log(amp), 1)
    assert np.sum((np.polyval(lin, t) - amp) ** 2) < 0.5 * np.sum((np.exp(np.polyval(ex, t)) - amp) ** 2)
    # per-cycle loss close to 4 mu / w0^2 (+ the small viscous part)
    tr = run.truth
    w0 = 2 * math.pi * tr["f0_hz"]
    loss = -lin[0] / tr["f0_hz"]
    assert 4 * tr["effect_params"]["mu"] / w0**2 < loss < 4 * tr["effect_params"]["mu"] / w0**2 + 2 * math.pi * tr["zeta"] * amp.max()
    # end stop: the excursion beyond the stop is clipped on one side only
    run = simulate_effect("cart", "end_stop", seed=0)
    p = run.truth["effect_params"]
    side_max = np.max(p["side"] * run.x)
    other_max = np.max(-p["side"] * run.x)
    assert side_max < abs(p["x_stop"]) + 0.3 * run.truth["amplitude"] < other_max + 0.3 * run.truth["amplitude"]
    assert side_max > abs(p["x_stop"])  # it does hit the stop


@pytest.mark.parametrize("system", SYSTEMS)
@pytest.mark.parametrize("seed", [0, 1])
def test_missing_dof_adds_a_second_frequency(system: str, seed: int) -> None:
    run = simulate_effect(system, "missing_dof", seed=seed, duration_s=20.0, n_episodes=2)
    p = run.truth["effect_params"]
    f1, f2 = p["f_modes_hz"] if system == "pendulum" else (run.truth["f0_hz"], p["f2_hz"])
    assert f2 / f1 == pytest.approx(p["f2_over_f0"], rel=1e-6)  # the drawn ratio of the modal frequencies
    assert not any(abs(f2 / f1 - k) < 0.15 for k in (2, 3))  # off the harmonics of the first mode
    x = run.latent[run.episode == 0]
    x = x - x.mean()
    f = np.fft.rfftfreq(4 * len(x), 1 / 30.0)
    P = np.abs(np.fft.rfft(x * np.hanning(len(x)), 4 * len(x))) ** 2
    band = lambda fc: P[np.abs(f - fc) < 0.05 * fc].max()
    between = P[(f > 1.15 * f1) & (f < 0.85 * f2)].max()
    assert band(f1) > band(f2) > 5 * between  # two spectral lines, the second one the 1-D chart cannot carry
    assert np.abs(run.second).max() > 0 and np.abs(run.x).max() <= MAX_EXCURSION[system]


def test_suite_lists_every_effect_on_both_systems_with_controls() -> None:
    suite = blind_suite()
    names = [s["name"] for s in suite]
    assert len(names) == len(set(names))
    for system in SYSTEMS:
        for effect in EFFECTS:
            clips = [s for s in suite if s["system"] == system and s["effect"] == effect]
            assert len(clips) >= 2
            assert len({c["seed"] for c in clips}) == len(clips)
        assert sum(1 for s in suite if s["system"] == system and s["effect"] == "none" and s["actuated"]) >= 2
    assert all(s["actuated"] for s in suite if s["effect"] == "actuation_delay")
    # two seeds draw different systems
    a, b = sample_truth("cart", "coulomb", 0), sample_truth("cart", "coulomb", 1)
    assert a["f0_hz"] != b["f0_hz"] and a["effect_params"]["mu"] != b["effect_params"]["mu"]
    assert sample_truth("cart", "coulomb", 0) == a  # reproducible


def test_clip_format_split_and_registration() -> None:
    clip = make_effect_clip("pendulum", "end_stop", seed=0, duration_s=3.0, n_episodes=3)
    T = 3 * 90
    assert clip.images.shape == (T, 64, 64, 3) and clip.images.dtype == np.uint8
    assert clip.meta["label"] == "end_stop" and clip.meta["system"] == "pendulum"
    assert len(clip.meta["latent"]) == T
    assert np.array_equal(np.unique(clip.episode), [0, 1, 2])
    assert np.all(clip.split[clip.episode == 2] == HELD_OUT) and np.all(clip.split[clip.episode < 2] == TRAIN)
    assert clip.u.shape == (T, 0)
    # the pictures move with the state: frames at the two extreme angles differ
    lat = np.asarray(clip.meta["latent"])
    assert np.abs(clip.images[np.argmax(lat)].astype(int) - clip.images[np.argmin(lat)].astype(int)).sum() > 1000
    # actuated clips log one channel; the generator is reachable from a system config
    act = make_clip({"source": {"synth": "effects", "params": {"system": "cart", "effect": "actuation_delay", "duration_s": 2.0, "n_episodes": 2}}})
    assert "effects" in GENERATORS
    assert act.u.shape == (120, 1) and act.u_names == ["u1"] and act.meta["label"] == "actuation_delay"


def test_bad_arguments_raise() -> None:
    with pytest.raises(ValueError, match="effect must be one of"):
        simulate_effect("cart", "magnetism")
    with pytest.raises(ValueError, match="system must be one of"):
        sample_truth("robot", "none")
    with pytest.raises(ValueError, match="actuated"):
        sample_truth("cart", "actuation_delay", actuated=False)
    with pytest.raises(ValueError, match="n_episodes"):
        simulate_effect("cart", "none", n_episodes=1)
    with pytest.raises(ValueError, match="n_per_effect"):
        blind_suite(0)


def test_smoothness_of_latent_is_physical() -> None:
    # no jumps between frames inside an episode (what a chart could encode continuously)
    run = simulate_effect("pendulum", "periodic_force", seed=0, duration_s=5.0, n_episodes=2)
    for e in range(2):
        x = run.latent[run.episode == e]
        d2 = np.abs(np.diff(x, 2))
        assert d2.max() < 10 * np.median(np.abs(np.diff(x))) + 1e-9
        assert np.allclose(gaussian_filter1d(x, 1.0), x, atol=0.05 * np.ptp(x))
