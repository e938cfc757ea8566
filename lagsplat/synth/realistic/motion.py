"""Ground-truth motion of the realistic suite's clips: one continuous take per clip.

The 1-DOF systems follow the laws of :mod:`lagsplat.synth.effects`
(``x'' = -w0^2 g(x) - 2 zeta w0 x' + a_eff``, one unmodelled effect or none),
integrated there; a clip keeps the first recording of
:func:`~lagsplat.synth.effects.simulate_effect` (one take, no cut):

* ``pendulum``: ``x`` is the swing angle (rad), ``g = sin``;
* ``spring_cart``: ``x`` is the cart's displacement (frame widths of the
  effect library; :data:`CART_METRES` metres each), ``g(x) = x``;
* ``torsion_disk``: the cart's linear law, read as a rotation about the camera
  axis, ``angle = x / A * amplitude_deg`` (``A`` the library's nominal
  amplitude), so the release amplitude is set exactly (60 or 120 degrees);
* ``double_pendulum``: two equal point-mass pendulums in series, no effect,
  integrated here (DOP853, ``rtol`` 1e-10), light linear joint damping.

Two motions outside the model class (no rest state to oscillate about), for
the checks that must name them rather than fit them:

* ``spin_down_motion``: the torsion disk without its spring, spun up and left
  to stop under viscous and dry friction (a rotation of several turns);
* ``slide_out_motion``: the cart without its spring, pushed so that it rolls
  out of the camera's view.

The hidden force is ``x'' - (-w0^2 g(x) - 2 zeta w0 x')`` per frame, ``x''``
from the integrated velocity by fourth-order central differences (:func:`acceleration_of`): what the nominal
damped oscillator of the clip's ``f0`` and ``zeta`` does not explain (zero,
up to the difference's error, for ``none``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.integrate import solve_ivp

from lagsplat.synth.effect_truth import NOMINAL_AMPLITUDE
from lagsplat.synth.effects import simulate_effect

__all__ = ["Motion", "CART_METRES", "coordinate_scale", "one_dof_motion", "double_pendulum_motion", "spin_down_motion", "slide_out_motion", "acceleration_of", "hidden_acceleration", "GRAVITY"]

CART_METRES = 1.0
"""Metres per frame width of the effect library's cart coordinate."""

GRAVITY = 9.81
"""m/s^2."""


@dataclass
class Motion:
    """One clip's ground truth, sampled at the frames.

    Attributes:
        t: ``[T]`` seconds, ``i / fps``.
        q: ``[T, d]`` generalized coordinates: rad (pendulum, torsion disk, double pendulum) or m (cart);
            for ``missing_dof`` a second column holds the hidden degree of freedom (pivot or second cart, m).
        qdot: ``[T, d]`` their rates, per second.
        hidden: ``[T]`` hidden generalized acceleration of the first coordinate (see the module docstring).
        f0_hz: natural frequency of the nominal oscillator (the slower mode for the double pendulum).
        truth: parameters (JSON-serialisable).
        extras: further arrays of the truth file, by key (the nuisance clips' observed frequency,
            :mod:`lagsplat.synth.realistic.nuisance`); empty for the suite's clips.
    """

    t: np.ndarray
    q: np.ndarray
    qdot: np.ndarray
    hidden: np.ndarray
    f0_hz: float
    truth: dict[str, Any] = field(default_factory=dict)
    extras: dict[str, np.ndarray] = field(default_factory=dict)


def acceleration_of(xd: np.ndarray, dt: float) -> np.ndarray:
    """``x''`` from sampled ``x' [T]``: fourth-order central differences inside, second-order one-sided at the two ends."""
    xdd = np.gradient(xd, dt, edge_order=2)
    xdd[2:-2] = (-xd[4:] + 8 * xd[3:-1] - 8 * xd[1:-3] + xd[:-4]) / (12 * dt)
    return xdd


def hidden_acceleration(x: np.ndarray, xd: np.ndarray, dt: float, f0: float, zeta: float, sine: bool) -> np.ndarray:
    """The part of the acceleration that the damped linear (or pendulum) law leaves unexplained, ``[T]``.

    ``a - (-w0^2 x - 2 zeta w0 xd)`` (``sin x`` for a pendulum) with ``a`` the finite-difference acceleration
    of ``xd`` (:func:`acceleration_of`), ``w0 = 2 pi f0``: the effect's own term, in ``x``'s units per s^2.
    """
    w0 = 2 * math.pi * f0
    return acceleration_of(xd, dt) + w0**2 * (np.sin(x) if sine else x) + 2 * zeta * w0 * xd


def coordinate_scale(system: str, truth: dict[str, Any]) -> float:
    """Units of a 1-DOF clip's ``q`` per unit of the effect library's ``x`` (module docstring).

    1 for the pendulum (rad), :data:`CART_METRES` for the spring cart, and for the torsion disk
    ``radians(amplitude_deg) / A`` (``truth["amplitude_deg"]``, ``A`` the library's nominal cart amplitude).

    Raises:
        ValueError: on a system other than ``pendulum``, ``spring_cart`` or ``torsion_disk``.
    """
    if system == "pendulum":
        return 1.0
    if system == "spring_cart":
        return CART_METRES
    if system == "torsion_disk":
        return math.radians(float(truth["amplitude_deg"])) / NOMINAL_AMPLITUDE["cart"]
    raise ValueError(f"unknown 1-DOF system {system!r}; known: pendulum, spring_cart, torsion_disk")


def one_dof_motion(system: str, effect: str, seed: int, fps: float, duration_s: float, amplitude_deg: float = 60.0) -> Motion:
    """Ground truth of a pendulum, spring cart or torsion disk clip (module docstring).

    Args:
        system: ``pendulum``, ``spring_cart`` or ``torsion_disk``.
        effect: a label of :data:`lagsplat.synth.effect_truth.EFFECTS` (``actuation_delay`` needs a logged input: not here).
        seed: draws the parameters and the release state.
        fps, duration_s: frame rate (Hz) and length (s) of the take.
        amplitude_deg: torsion disk only: the release amplitude, degrees.

    Raises:
        ValueError: on an unknown system, ``actuation_delay``, or ``missing_dof`` for the torsion disk.
    """
    if effect == "actuation_delay":
        raise ValueError("actuation_delay needs a logged actuation signal; the realistic suite is video only")
    base = {"pendulum": "pendulum", "spring_cart": "cart", "torsion_disk": "cart"}.get(system)
    if base is None:
        raise ValueError(f"unknown 1-DOF system {system!r}; known: pendulum, spring_cart, torsion_disk")
    if system == "torsion_disk" and effect == "missing_dof":
        raise ValueError("the torsion disk has no second body to carry a missing degree of freedom")
    run = simulate_effect(base, effect, seed, actuated=False, fps=fps, duration_s=duration_s, n_episodes=2, held_out_episodes=1)
    first = run.episode == 0
    t, x, xd, second = run.t[first], run.x[first], run.xdot[first], run.second[first]
    tr = dict(run.truth)
    f0, zeta = float(tr["f0_hz"]), float(tr["zeta"])
    hidden = hidden_acceleration(x, xd, 1.0 / fps, f0, zeta, sine=base == "pendulum")
    if system == "torsion_disk":
        tr["amplitude_deg"] = float(amplitude_deg)
    k = coordinate_scale(system, tr)
    x, xd, hidden = x * k, xd * k, hidden * k
    if system == "spring_cart":  # the second cart of the missing degree of freedom, in the same units
        second = second * k
    q = np.stack([x, second], 1) if effect == "missing_dof" else x[:, None]
    qd = np.stack([xd, np.gradient(second, 1.0 / fps)], 1) if effect == "missing_dof" else xd[:, None]
    return Motion(t - t[0], q, qd, hidden, f0, tr)


def double_pendulum_motion(seed: int, fps: float, duration_s: float, amplitude_deg: float, length_m: float = 0.3, zeta: float = 0.01) -> Motion:
    """Two equal point-mass pendulums in series (rod length ``length_m`` each), released from rest.

    Equations of motion: the standard double pendulum (Lagrange), plus joint damping
    ``-c theta_dot`` with ``c`` giving damping ratio ``zeta`` on the slow mode.
    ``f0_hz`` is the slow small-angle mode, ``sqrt((2 - sqrt 2) g / l) / 2 pi``.
    """
    g, l_ = GRAVITY, float(length_m)
    w_slow = math.sqrt((2 - math.sqrt(2)) * g / l_)
    c = 2 * zeta * w_slow
    rng = np.random.default_rng([int(seed), 2, 11])
    a = math.radians(amplitude_deg)
    y0 = [a, a * math.sqrt(2) * rng.uniform(0.8, 1.2), 0.0, 0.0]  # near the slow mode's shape (1, sqrt 2)

    def rhs(_t, y):
        t1, t2, w1, w2 = y
        d = t1 - t2
        den = 3 - math.cos(2 * d)
        a1 = (-3 * g * math.sin(t1) - g * math.sin(t1 - 2 * t2) - 2 * math.sin(d) * (w2**2 * l_ + w1**2 * l_ * math.cos(d))) / (l_ * den)
        a2 = 2 * math.sin(d) * (2 * w1**2 * l_ + 2 * g * math.cos(t1) + w2**2 * l_ * math.cos(d)) / (l_ * den)
        return [w1, w2, a1 - c * w1, a2 - c * w2]

    n = int(round(duration_s * fps))
    t = np.arange(n) / fps
    sol = solve_ivp(rhs, (0.0, t[-1]), y0, t_eval=t, method="DOP853", rtol=1e-10, atol=1e-12, max_step=1.0 / fps)
    if not sol.success:
        raise ValueError(f"double pendulum integration failed: {sol.message}")
    q, qd = sol.y[:2].T, sol.y[2:].T
    truth = {"system": "double_pendulum", "effect": "none", "length_m": l_, "zeta": zeta, "amplitude_deg": float(amplitude_deg), "f0_hz": w_slow / (2 * math.pi)}
    return Motion(t, q, qd, np.zeros(n), w_slow / (2 * math.pi), truth)


def _friction_stop(v0: float, c: float, mu: float, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position and velocity under ``x'' = -c x' - mu sign(x')`` from ``(0, v0 > 0)``: ``(x [T], x' [T])``, at rest after the stop."""
    k = mu / c
    t_stop = math.log((v0 + k) / k) / c
    ts = np.minimum(t, t_stop)
    v = np.where(t < t_stop, (v0 + k) * np.exp(-c * ts) - k, 0.0)
    x = (v0 + k) * (1 - np.exp(-c * ts)) / c - k * ts
    return x, v


def spin_down_motion(seed: int, fps: float, duration_s: float) -> Motion:
    """The torsion disk with no spring, spun up to about 0.9 turns/s and stopping after about 7 s (module docstring).

    ``q`` is the disk's angle (rad), monotone; ``hidden`` the friction's angular acceleration;
    ``f0_hz`` is ``nan`` (there is no natural frequency).
    """
    rng = np.random.default_rng([int(seed), 5, 3])
    w0 = 2 * math.pi * rng.uniform(0.8, 1.0)
    c, t_stop = 0.2, rng.uniform(6.5, 7.5)
    mu = w0 * c / (math.exp(c * t_stop) - 1)
    t = np.arange(int(round(duration_s * fps))) / fps
    x, v = _friction_stop(w0, c, mu, t)
    hidden = np.where(v > 0, -c * v - mu, 0.0)
    truth = {"system": "torsion_disk", "effect": "spin_down", "omega0_rad_s": w0, "viscous_per_s": c, "coulomb_rad_s2": mu,
             "stop_s": t_stop, "turns": float(x[-1] / (2 * math.pi)), "f0_hz": float("nan"), "outside_class": "rotation"}  # fmt: skip
    return Motion(t, x[:, None], v[:, None], hidden, float("nan"), truth)


def slide_out_motion(seed: int, fps: float, duration_s: float) -> Motion:
    """The spring cart with no spring, pushed from 0.3 m left of centre at about 0.6 m/s: it rolls out of view (module docstring).

    ``q`` is the cart's position (m); ``hidden`` the rolling friction's acceleration; ``f0_hz`` is ``nan``.
    """
    rng = np.random.default_rng([int(seed), 5, 4])
    v0, c, mu = rng.uniform(0.55, 0.65), 0.05, 0.01
    t = np.arange(int(round(duration_s * fps))) / fps
    x, v = _friction_stop(v0, c, mu, t)
    hidden = np.where(v > 0, -c * v - mu, 0.0)
    truth = {"system": "spring_cart", "effect": "slide_out", "v0_m_s": v0, "viscous_per_s": c, "coulomb_m_s2": mu,
             "f0_hz": float("nan"), "outside_class": "leaves_frame"}  # fmt: skip
    return Motion(t, (x - 0.3)[:, None], v[:, None], hidden, float("nan"), truth)
