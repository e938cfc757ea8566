"""Simple systems with one known unmodelled effect each: the withheld data of the gap diagnosis.

Every clip shows one of two 1-DOF systems, a pendulum or a cart on a spring,
whose motion obeys a linear-damping law plus *exactly one* candidate effect of
:mod:`lagsplat.diagnose.effects` (or none: the control). The label is stored in
``clip.meta["label"]``; a diagnosis that is run blind reads it only to score.

Physics
-------
The generalized coordinate ``x`` is the pendulum angle (rad, from the downward
vertical) or the cart displacement (frame widths). With ``w0 = 2 pi f0``::

    x'' = -w0^2 g(x) - 2 zeta w0 x' + a_eff(x, x', t) + b u(t - tau)

``g(x) = sin x`` (pendulum) or ``x`` (cart); ``u`` is a logged, non-negative
actuation (``actuated`` clips only; ``tau = 0`` except for the delay effect).
Effect magnitudes are set relative to the nominal amplitude ``A`` (20 deg or
0.25 frame widths) and the restoring acceleration ``w0^2 A``:

=================== ======================================================================
label               ``a_eff`` (``A`` nominal amplitude, ``kappa`` a drawn relative strength)
=================== ======================================================================
``none``            0 (control)
``coulomb``         ``-mu tanh(x' / v_s)``, ``mu = kappa w0^2 A``, ``v_s = 0.002 w0 A``
``quadratic_drag``  ``-c2 |x'| x'``, ``c2 = kappa / A``
``end_stop``        ``-k_s w0^2 relu(side (x - x_s)) side``: a stiff one-sided spring at ``x_s``
``cubic_stiffness`` ``-eps w0^2 x^3 / A^2`` (``eps > 0`` hardening, ``< 0`` softening)
``periodic_force``  ``kappa w0^2 A cos(Omega t + phi)``, unlogged, ``Omega / w0`` in
                    ``[2.2, 2.7]`` or ``[0.35, 0.55]`` (off resonance and off the harmonics),
                    ``t`` the clip time (continuous over the episodes)
``drift``           stiffness ``w0^2 (1 + alpha (t / T_clip - 1/2))`` or damping ratio
                    ``zeta(t)`` rising linearly over the clip
``actuation_delay`` the logged ``u`` acts ``tau`` seconds late (actuated clips)
``missing_dof``     a second, coupled degree of freedom: the cart drags a lighter second
                    cart through a spring (both drawn); the pendulum hangs from a pivot
                    sliding on a horizontal spring (pivot drawn moving); the ratio of the
                    two modal frequencies is in ``[1.45, 1.8]`` or ``[2.2, 2.6]``
=================== ======================================================================

Each effect's parameters are drawn from ``np.random.default_rng`` seeded by
``(seed, system, effect)`` and stored in ``meta["truth"]``. Trajectories are
integrated with ``scipy.integrate.solve_ivp`` (DOP853, ``rtol = 1e-9``,
step at most one frame; LSODA for the stiff Coulomb switch and end stop)
and sampled at ``t_i = i / fps``.

Clip
----
``n_episodes`` recordings of ``duration_s`` seconds, stored back to back as in
:func:`~lagsplat.synth.coupled_carts_clip.make_coupled_carts_clip`: episode ``e``
starts from its own seeded state (amplitude ``0.75..1 A``, random phase); the
last ``held_out_episodes`` are held out. ``meta["latent"]`` holds the 1-D
coordinate a one-dimensional chart reads (the angle ``x``, or the main cart's
displacement), which the latent-level benchmark uses in place of Stage 1.

Picture: the pendulum in the style of :mod:`lagsplat.synth.pendulum`, the
cart in the style of :mod:`lagsplat.synth.coupled_carts`, with a static
bumper drawn where an end stop sits; 64 x 64 by default.
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.integrate import solve_ivp

from lagsplat.io.clip import HELD_OUT, TRAIN
from lagsplat.synth._clip import check_timing
from lagsplat.synth.effect_truth import MAX_EXCURSION, sample_truth
from lagsplat.synth.coupled_carts import (
    CoupledCarts,
)

__all__ = ["EffectRun", "simulate_effect", "true_acceleration"]


@dataclass
class EffectRun:
    """One simulated clip before rendering.

    Attributes:
        system: ``"pendulum"`` or ``"cart"``.
        effect: the label (one of :data:`~lagsplat.synth.effect_truth.EFFECTS`).
        t: float64 ``[T]`` clip time, s (``i / fps``, continuous over episodes).
        x: float64 ``[T]`` generalized coordinate: rad (pendulum) or frame widths (cart).
        xdot: float64 ``[T]`` its rate, per second.
        latent: float64 ``[T]`` what a 1-D chart reads (equal to ``x`` here).
        second: float64 ``[T]`` the missing degree of freedom (pivot displacement in rod
            lengths, or the second cart in frame widths), zeros for other effects.
        u: float32 ``[T,n_u]`` logged actuation (``n_u`` is 1 for actuated clips, else 0).
        episode: int16 ``[T]`` recording index.
        split: int8 ``[T]`` ``TRAIN`` / ``HELD_OUT`` (the last episodes held out).
        truth: JSON-serialisable physical parameters (base system and effect).
    """

    system: str
    effect: str
    t: np.ndarray
    x: np.ndarray
    xdot: np.ndarray
    latent: np.ndarray
    second: np.ndarray
    u: np.ndarray
    episode: np.ndarray
    split: np.ndarray
    truth: dict[str, Any] = field(default_factory=dict)


def _input(truth: dict[str, Any]) -> Callable[[np.ndarray | float], np.ndarray | float]:
    """The logged actuation ``u(t) >= 0`` (a sum of sinusoids around its amplitude sum; in [0, 2])."""
    a = truth["actuation"]
    f, amp, ph = (np.asarray(a[k]) for k in ("freqs_hz", "amps", "phases"))

    def u(t: np.ndarray | float) -> np.ndarray | float:
        tt = np.asarray(t, dtype=np.float64)[..., None]
        return (amp.sum() + (amp * np.sin(2 * math.pi * f * tt + ph)).sum(-1)).astype(np.float64)

    return u


def true_acceleration(truth: dict[str, Any], T_clip: float) -> Callable[[Any, Any, Any], np.ndarray]:
    """The law of a 1-DOF clip, ``x'' = a(t, x, x')``, for every effect except ``missing_dof`` (module docstring).

    Args:
        truth: the clip's ``meta["truth"]`` (:func:`~lagsplat.synth.effect_truth.sample_truth`).
        T_clip: the clip's length, s (the drift's time scale).

    Returns:
        ``a(t, x, xdot)``: the acceleration (units of ``x`` per s^2), elementwise over
        broadcastable arrays (or floats) of time (s), position and rate.

    Raises:
        ValueError: for ``missing_dof`` (two degrees of freedom, no 1-DOF law).
    """
    system, effect = truth["system"], truth["effect"]
    if effect == "missing_dof":
        raise ValueError("missing_dof has two degrees of freedom; its law is _rhs_pivot / the coupled carts")
    w0 = 2 * math.pi * truth["f0_hz"]
    zeta, A, p = truth["zeta"], truth["amplitude"], truth["effect_params"]
    g = np.sin if system == "pendulum" else (lambda x: x)
    u = _input(truth) if truth["actuated"] else None
    gain = truth["actuation"]["gain"] if u is not None else 0.0
    tau = p.get("tau_s", 0.0)

    def law(t: Any, x: Any, v: Any) -> np.ndarray:
        k2, z = w0 * w0, zeta
        if effect == "drift":
            if p["kind"] == "stiffness":
                k2 = w0 * w0 * (1.0 + p["alpha"] * (t / T_clip - 0.5))
            else:
                z = p["zeta_start"] + (p["zeta_end"] - p["zeta_start"]) * t / T_clip
        a = -k2 * g(x) - 2.0 * z * w0 * v
        if effect == "coulomb":
            a = a - p["mu"] * np.tanh(v / p["v_s"])
        elif effect == "quadratic_drag":
            a = a - p["c2"] * np.abs(v) * v
        elif effect == "end_stop":
            a = a - p["k_ratio"] * w0 * w0 * np.maximum(p["side"] * (x - p["x_stop"]), 0.0) * p["side"]
        elif effect == "cubic_stiffness":
            a = a - p["eps"] * w0 * w0 * x**3 / A**2
        elif effect == "periodic_force":
            a = a + p["amplitude"] * np.cos(2 * math.pi * p["f_hz"] * t + p["phase"])
        if u is not None:
            a = a + gain * u(t - tau)
        return a

    return law


def _rhs_1dof(truth: dict[str, Any], T_clip: float) -> Callable[[float, np.ndarray], np.ndarray]:
    """Right-hand side of ``y = (x, x')`` for every effect except ``missing_dof`` (:func:`true_acceleration`)."""
    law = true_acceleration(truth, T_clip)

    def rhs(t: float, y: np.ndarray) -> np.ndarray:
        return np.array([y[1], float(law(t, y[0], y[1]))])

    return rhs


def _rhs_pivot(truth: dict[str, Any]) -> Callable[[float, np.ndarray], np.ndarray]:
    """Pendulum on a horizontally sprung pivot, ``y = (theta, X, theta', X')``, ``X`` in rod lengths.

    From ``T = 1/2 (M + m) L^2 X'^2 + m L^2 X' theta' cos theta + 1/2 m L^2 theta'^2``,
    ``V = 1/2 k X^2 L^2 - m g L cos theta``, divided by ``m L^2`` resp. ``(M + m) L^2``
    (``mu = m / (M + m)``)::

        theta'' + X'' cos theta           = -w0^2 sin theta - 2 zeta w0 theta'
        X'' + mu (theta'' cos theta - theta'^2 sin theta) = -wp^2 X - 2 zeta_p wp X'
    """
    w0 = 2 * math.pi * truth["f0_hz"]
    p = truth["effect_params"]
    wp = w0 * p["pivot_over_f0"]
    mu, zp, z = p["mass_ratio"], p["zeta2"], truth["zeta"]

    def rhs(_t: float, y: np.ndarray) -> np.ndarray:
        th, X, om, V = y
        c, s = math.cos(th), math.sin(th)
        Mm = np.array([[1.0, c], [mu * c, 1.0]])
        b = np.array([-w0 * w0 * s - 2 * z * w0 * om, mu * om * om * s - wp * wp * X - 2 * zp * wp * V])
        acc = np.linalg.solve(Mm, b)
        return np.array([om, V, acc[0], acc[1]])

    return rhs


def _integrate(rhs: Callable, y0: np.ndarray, t: np.ndarray, stiff: bool) -> np.ndarray:
    dt = float(t[1] - t[0]) if len(t) > 1 else 1.0
    sol = solve_ivp(
        rhs, (float(t[0]), float(t[-1])), y0, method="LSODA" if stiff else "DOP853", t_eval=t,
        rtol=1e-9, atol=1e-11, max_step=dt,
    )  # fmt: skip
    if not sol.success or sol.y.shape[1] != len(t):
        raise ValueError(f"effect simulation failed: {sol.message}")
    return sol.y.T


def simulate_effect(
    system: str = "pendulum",
    effect: str = "none",
    seed: int = 0,
    actuated: bool | None = None,
    fps: float = 30.0,
    duration_s: float = 15.0,
    n_episodes: int = 4,
    held_out_episodes: int = 1,
) -> EffectRun:
    """Simulate one clip's motion (no pictures).

    Args:
        system: ``"pendulum"`` or ``"cart"``.
        effect: one of :data:`~lagsplat.synth.effect_truth.EFFECTS`.
        seed: seeds the parameters (:func:`sample_truth`) and the episode starts.
        actuated: see :func:`sample_truth`.
        fps: frame rate, Hz.
        duration_s: length of each episode, s.
        n_episodes: recordings (>= 2: the last ``held_out_episodes`` are held out).
        held_out_episodes: in ``[1, n_episodes - 1]``.

    Returns:
        The :class:`EffectRun`.

    Raises:
        ValueError: on invalid arguments, a failed integration, or an
            excursion beyond what the picture accepts (:data:`MAX_EXCURSION`).
    """
    fps_f, dur = check_timing(fps, duration_s)
    n_ep, n_ho = int(n_episodes), int(held_out_episodes)
    if n_ep < 2 or not (1 <= n_ho < n_ep):
        raise ValueError(f"need n_episodes >= 2 and 1 <= held_out_episodes < n_episodes, got {n_episodes}, {held_out_episodes}")
    truth = sample_truth(system, effect, seed, actuated)
    T_e = int(round(dur * fps_f))
    if T_e < 16:
        raise ValueError(f"each episode has {T_e} frames; need at least 16")
    T = n_ep * T_e
    T_clip = T / fps_f
    t_all = np.arange(T, dtype=np.float64) / fps_f
    rng = np.random.default_rng([int(seed), 7, zlib.crc32(f"{system}/{effect}".encode())])
    A = truth["amplitude"]
    w0 = 2 * math.pi * truth["f0_hz"]
    p = truth["effect_params"]
    x = np.empty(T)
    xd = np.empty(T)
    second = np.zeros(T)
    for e in range(n_ep):
        sl = slice(e * T_e, (e + 1) * T_e)
        t = t_all[sl]
        r = rng.uniform(0.75, 1.0)
        phase = rng.uniform(0, 2 * math.pi)
        if effect == "end_stop":  # start on the free side of the stop, moving towards it
            phase = math.pi / 2 * (1 if rng.uniform() < 0.5 else 3) + rng.uniform(-0.4, 0.4)
        x0, v0 = r * A * math.cos(phase), -r * A * w0 * math.sin(phase)
        if truth["actuated"]:  # half the free amplitude, around the equilibrium loaded by the mean input
            x0 = 0.5 * x0 + truth["actuation"]["gain"] * float(np.sum(truth["actuation"]["amps"])) / w0**2
            v0 = 0.5 * v0
        if effect == "missing_dof" and system == "cart":
            xs, vs = _two_carts(truth, r, phase, rng, fps_f, T_e)
            x[sl], xd[sl], second[sl] = xs[:, 0], vs[:, 0], xs[:, 1]
            continue
        if effect == "missing_dof":
            X0 = p["pivot_amp"] * (1 if rng.uniform() < 0.5 else -1) * rng.uniform(0.7, 1.0)
            y = _integrate(_rhs_pivot(truth), np.array([x0, X0, v0 / 1.0, 0.0]), t, stiff=False)
            x[sl], xd[sl], second[sl] = y[:, 0], y[:, 2], y[:, 1]
            continue
        stiff = effect in ("coulomb", "end_stop")
        y = _integrate(_rhs_1dof(truth, T_clip), np.array([x0, v0]), t, stiff)
        x[sl], xd[sl] = y[:, 0], y[:, 1]
    peak = float(np.max(np.abs(x)))
    if peak > MAX_EXCURSION[system]:
        raise ValueError(f"{system}/{effect} seed {seed}: excursion {peak:.3f} exceeds {MAX_EXCURSION[system]:.3f}")
    u = np.zeros((T, 0), np.float32)
    if truth["actuated"]:
        u = _input(truth)(t_all)[:, None].astype(np.float32)
    episode = np.repeat(np.arange(n_ep, dtype=np.int16), T_e)
    split = np.where(episode >= n_ep - n_ho, HELD_OUT, TRAIN).astype(np.int8)
    truth["n_episodes"], truth["held_out_episodes"], truth["fps"], truth["duration_s"] = n_ep, n_ho, fps_f, dur
    return EffectRun(system, effect, t_all, x, xd, x.copy(), second, u, episode, split, truth)


def _two_carts(
    truth: dict[str, Any], r: float, phase: float, rng: np.random.Generator, fps: float, n: int
) -> tuple[np.ndarray, np.ndarray]:
    """Missing DOF of the cart: the main cart coupled to a lighter second cart (exact linear motion).

    Mode 1 (at ``f0``) carries amplitude ``r A`` in the main cart's displacement,
    mode 2 a share ``mode2_share`` of it, with independent random phases.
    """
    from lagsplat.synth.coupled_carts import simulate_coupled_carts

    p = truth["effect_params"]
    f0 = truth["f0_hz"]
    sysc = CoupledCarts.from_modes((f0, f0 * p["f2_over_f0"]), (truth["zeta"], p["zeta2"]), (1.0, p["m2"]), p["m2"])
    Phi = sysc.mode_shapes
    A = truth["amplitude"]
    amp = np.array([r * A / abs(Phi[0, 0]), p["mode2_share"] * r * A / abs(Phi[0, 1])])
    ph = np.array([phase, rng.uniform(0, 2 * math.pi)])
    wd = 2 * math.pi * sysc.f_modes_damped_hz
    zw = sysc.decay_rates
    q0 = amp * np.cos(ph)
    dq0 = amp * (-zw * np.cos(ph) - wd * np.sin(ph))
    xs, vs, _ = simulate_coupled_carts(sysc, Phi @ q0, Phi @ dq0, fps, n)
    big = float(np.max(np.abs(xs)))
    if big > MAX_EXCURSION["cart"]:  # keep both carts clear of the walls
        xs, vs = xs * MAX_EXCURSION["cart"] / big, vs * MAX_EXCURSION["cart"] / big
    truth.setdefault("effect_params", {})["f2_hz"] = float(sysc.f_modes_hz[1])
    return xs, vs
