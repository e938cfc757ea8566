"""Ground-truth motion of the nuisance clips (:mod:`lagsplat.synth.realistic.nuisance`).

Every law here is one of the diagnosis library's (:func:`lagsplat.synth.effects.true_acceleration`,
``x'' = -w0^2 g(x) - 2 zeta w0 x' + a_eff``, ``g = sin`` for the pendulum, ``g(x) = x`` for the cart),
with parameters the library does not draw:

* :func:`sticks_motion`: its ``coulomb`` law (``a_eff = -mu tanh(x' / v_s)``) with a friction strong
  enough that the object swings a few times and then sticks off-centre. Dry friction holds a body at
  rest wherever the restoring force does not exceed the static friction, ``w0^2 |g(x)| <= mu_s``
  (``mu_s = STATIC_OVER_KINETIC mu``); the library's smooth ``tanh`` would instead let it creep, so the
  take is integrated swing by swing and held still from the first turning point inside that zone.
  The parameters are chosen with the exact map of a linear oscillator with Coulomb and viscous
  friction from one turning point to the next (Den Hartog, "Mechanical Vibrations", 1956, section 8.2):
  ``|X_{k+1}| = rho (|X_k| - d) - d``, ``d = mu / w0^2``, ``rho = exp(-zeta w0 pi / w_d)``, every half
  swing lasting ``pi / w_d``, ``w_d = w0 sqrt(1 - zeta^2)``.
* :func:`long_string_motion`: a pendulum on a long string, its frequency that of its length,
  ``f0 = sqrt(g / L) / 2 pi`` (no effect).
* :func:`short_duration_s`: the length of a take of a given number of observed periods.

:func:`observed` measures, from a sampled true trajectory, what a camera sees of it: the time the
motion stops (``moving_until_s``) and the frequency over the moving part (``observed_hz``, from the
turning points, and ``observed_hz_spectral``, :func:`lagsplat.timeseries.spectral_peak_frequency`).
Units: s, Hz, rad (pendulum) or m (cart, :data:`~lagsplat.synth.realistic.motion.CART_METRES` per
library unit, 1).
"""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from lagsplat.synth.effect_truth import NOMINAL_AMPLITUDE, sample_truth
from lagsplat.synth.effects import true_acceleration
from lagsplat.synth.realistic.motion import GRAVITY, Motion, hidden_acceleration, coordinate_scale, one_dof_motion
from lagsplat.timeseries import spectral_peak_frequency

__all__ = ["STATIC_OVER_KINETIC", "observed", "turning_times", "sticks_motion", "coulomb_for_stop", "long_string_motion", "short_duration_s"]


STATIC_OVER_KINETIC = 2.0
"""Static over kinetic dry-friction coefficient of the ``sticks`` clips (it sets how far off-centre they stop)."""


def turning_times(t: np.ndarray, qdot: np.ndarray) -> np.ndarray:
    """Times (s) where the rate ``qdot [T]`` changes sign, linearly interpolated between frames."""
    v = np.asarray(qdot, np.float64)
    i = np.nonzero(v[:-1] * v[1:] < 0)[0]
    return t[i] + (t[i + 1] - t[i]) * v[i] / (v[i] - v[i + 1])


def observed(t: np.ndarray, q: np.ndarray, qdot: np.ndarray) -> dict[str, float]:
    """What a camera sees of a 1-DOF take ``q, qdot [T]`` sampled at ``t [T]`` (s).

    Returns:
        ``moving_until_s``: the first frame time from which ``q`` stays at its final value (to 1e-9 of
        its range), or the take's end (``t[-1] + dt``) if it never stops; ``observed_hz``: the frequency
        over the moving part from its turning points, ``(n - 1) / (2 (t_n - t_1))`` over the ``n`` sign
        changes of ``qdot`` there, ``nan`` with fewer than 3;
        ``observed_hz_spectral``: the spectral peak over the moving part; ``observed_periods``: the
        moving part's length times ``observed_hz``.
    """
    t, q, qdot = (np.asarray(a, np.float64).reshape(len(t), -1)[:, 0] for a in (t, q, qdot))
    dt = float(t[1] - t[0])
    moved = np.abs(q - q[-1]) > 1e-9 * max(float(np.ptp(q)), 1e-12)
    last = int(np.nonzero(moved)[0][-1]) if moved.any() else -1
    stops = last < len(q) - 2 and bool(np.all(qdot[last + 1 :] == 0.0))
    until = float(t[last + 1]) if stops else float(t[-1] + dt)
    part = t < until
    turns = turning_times(t[part], qdot[part])
    f_turn = (len(turns) - 1) / (2.0 * (turns[-1] - turns[0])) if len(turns) >= 3 else float("nan")
    f_spec = spectral_peak_frequency(q[part], dt) if part.sum() >= 8 else float("nan")
    return {"moving_until_s": until, "observed_hz": float(f_turn), "observed_hz_spectral": float(f_spec), "observed_periods": float(until * f_turn)}


def coulomb_for_stop(x0: float, half_swings: int, zeta: float, rest_share: float = 0.85, static: float = STATIC_OVER_KINETIC) -> float:
    """The kinetic friction over the stiffness, ``d = mu / w0^2`` (units of ``x0``), that stops a linear oscillator
    released from rest at ``x0 > 0`` after ``half_swings`` half swings, at ``rest_share * static * d`` from the
    centre (inside the static zone ``static * d``; the turning-point map of the module docstring)."""
    rho = math.exp(-zeta * math.pi / math.sqrt(1.0 - zeta * zeta))

    def gap(d: float) -> float:
        x = x0
        for _ in range(half_swings):
            x = rho * (x - d) - d
        return x - rest_share * static * d

    return float(brentq(gap, 1e-9 * x0, x0))


def _stick_slip(law, w0: float, mu_static: float, sine: bool, x0: float, t: np.ndarray, v_eps: float) -> tuple[np.ndarray, np.ndarray]:
    """Integrate ``x'' = law(t, x, x')`` from rest at ``x0`` (LSODA, as the library's Coulomb clips), swing by
    swing; at each approach to a turning point (``|x'|`` falling through ``v_eps``) the body sticks for good if
    ``w0^2 |g(x)| <= mu_static``. Returns ``(x [T], x' [T])`` at the times ``t``."""
    g = math.sin if sine else (lambda v: v)
    x, xd = np.empty(len(t)), np.empty(len(t))
    t0, y, sign = float(t[0]), np.array([x0, 0.0]), -1.0 if x0 > 0 else 1.0  # the sign of the coming motion
    dt = float(t[1] - t[0])
    while True:
        def approach(_t, yy, s=sign):
            return yy[1] - s * v_eps

        approach.terminal, approach.direction = True, -sign  # |x'| falling through v_eps
        sol = solve_ivp(lambda tt, yy: [yy[1], float(law(tt, yy[0], yy[1]))], (t0, float(t[-1])), y, method="LSODA",
                        events=approach, dense_output=True, rtol=1e-9, atol=1e-11, max_step=dt)  # fmt: skip
        if not sol.success:
            raise ValueError(f"stick-slip integration failed: {sol.message}")
        end = float(sol.t_events[0][0]) if len(sol.t_events[0]) else float(t[-1]) + 1.0
        seg = (t >= t0) & (t < end) if t0 > t[0] else t < end
        x[seg], xd[seg] = sol.sol(t[seg])
        if end > t[-1]:
            return x, xd
        y_end = sol.y_events[0][0]
        if w0 * w0 * abs(g(float(y_end[0]))) <= mu_static:  # static friction holds it
            rest = t >= end
            x[rest], xd[rest] = float(y_end[0]), 0.0
            return x, xd
        t0, y, sign = end, np.array(y_end, np.float64), -sign


def sticks_motion(system: str, seed: int, fps: float, duration_s: float, half_swings: int, stop_s: float, zeta: float = 0.02) -> Motion:
    """A pendulum or spring cart with strong dry friction: ``half_swings`` half swings, then stuck off-centre from about ``stop_s``.

    The base oscillator is the library's ``coulomb`` draw for ``seed`` (:func:`~lagsplat.synth.effect_truth.sample_truth`),
    with its frequency and damping ratio replaced so that the half swings end near ``stop_s`` (``f0`` from
    ``half_swings / (2 stop_s)``) and its friction chosen by :func:`coulomb_for_stop`; released from rest at
    0.85 to 1 of the nominal amplitude. ``truth["effect_params"]`` holds the kinetic ``mu`` (library units of
    ``x`` per s^2), ``kappa = mu / (w0^2 A)``, ``mu_static`` and ``static_zone`` (``mu_static / w0^2``, where it
    can stick).
    """
    base = {"pendulum": "pendulum", "spring_cart": "cart"}[system]
    tr = sample_truth(base, "coulomb", int(seed))
    rng = np.random.default_rng([int(seed), 31, 7])
    A = NOMINAL_AMPLITUDE[base]
    x0 = A * float(rng.uniform(0.85, 1.0))
    f0 = half_swings / (2.0 * stop_s * math.sqrt(1.0 - zeta * zeta))
    w0 = 2 * math.pi * f0
    d = coulomb_for_stop(x0, half_swings, zeta)
    if base == "pendulum":  # the same zone in angle: sin d = mu / w0^2
        d = math.asin(min(d, 1.0))
    mu = w0 * w0 * (math.sin(d) if base == "pendulum" else d)
    p = {"kappa": mu / (w0 * w0 * A), "mu": mu, "v_s": 0.002 * w0 * A, "mu_static": STATIC_OVER_KINETIC * mu, "static_zone": STATIC_OVER_KINETIC * d}
    tr.update({"f0_hz": f0, "zeta": zeta, "effect_params": p, "release": x0, "half_swings": int(half_swings)})
    n = int(round(duration_s * fps))
    t = np.arange(n) / fps
    law = true_acceleration(tr, T_clip=duration_s)
    x, xd = _stick_slip(law, w0, p["mu_static"], base == "pendulum", x0, t, v_eps=5 * p["v_s"])
    hidden = hidden_acceleration(x, xd, 1.0 / fps, f0, zeta, sine=base == "pendulum")
    k = coordinate_scale(system, tr)
    return Motion(t, (x * k)[:, None], (xd * k)[:, None], hidden * k, f0, tr)


def long_string_motion(seed: int, fps: float, duration_s: float, length_m: float, amplitude_deg: float, zeta: float = 0.004) -> Motion:
    """A small bob on a string ``length_m`` long, released from rest at ``amplitude_deg`` (the library's ``none`` law,
    ``f0 = sqrt(g / L) / 2 pi``, DOP853). The bob's height, ``-L cos q``, moves at twice the swing's frequency;
    ``truth["bob_vertical_m"]`` is its rise at the release, ``L (1 - cos amplitude)``."""
    tr = sample_truth("pendulum", "none", int(seed))
    f0 = math.sqrt(GRAVITY / length_m) / (2 * math.pi)
    a = math.radians(amplitude_deg)
    tr.update({"f0_hz": f0, "zeta": zeta, "length_m": float(length_m), "amplitude_deg": float(amplitude_deg), "bob_vertical_m": length_m * (1 - math.cos(a))})
    law = true_acceleration(tr, T_clip=duration_s)
    n = int(round(duration_s * fps))
    t = np.arange(n) / fps
    sol = solve_ivp(lambda tt, y: [y[1], float(law(tt, y[0], y[1]))], (0.0, float(t[-1])), [a, 0.0], t_eval=t, method="DOP853",
                    rtol=1e-10, atol=1e-12, max_step=1.0 / fps)  # fmt: skip
    if not sol.success:
        raise ValueError(f"long-string pendulum integration failed: {sol.message}")
    x, xd = sol.y
    return Motion(t, x[:, None], xd[:, None], hidden_acceleration(x, xd, 1.0 / fps, f0, zeta, sine=True), f0, tr)


@functools.lru_cache(maxsize=None)
def short_duration_s(system: str, seed: int, periods: float, fps: float = 30.0) -> float:
    """Length (s, a whole number of frames) of a take of ``system``'s no-effect motion for ``seed``
    (:func:`~lagsplat.synth.realistic.motion.one_dof_motion`) holding ``periods`` observed periods
    (``observed_hz`` of a 12-s take)."""
    m = one_dof_motion(system, "none", int(seed), fps, 12.0)
    f = observed(m.t, m.q[:, 0], m.qdot[:, 0])["observed_hz"]
    return round(periods / f * fps) / fps


def nuisance_truth(m: Motion) -> dict[str, Any]:
    """The arrays and scalars a nuisance clip adds to its truth file: :func:`observed` of ``m``'s first coordinate."""
    return observed(m.t, m.q[:, 0], m.qdot[:, 0])
