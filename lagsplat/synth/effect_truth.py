"""What a clip of the blind suite is: the effect labels, the systems, and the physical parameters each label draws.

:func:`sample_truth` draws, reproducibly from ``(seed, system, effect)``, the
base oscillator and the effect's parameters that
:func:`lagsplat.synth.effects.simulate_effect` integrates.
"""

from __future__ import annotations

import math
import zlib
from typing import Any

import numpy as np

__all__ = ["EFFECTS", "SYSTEMS", "NOMINAL_AMPLITUDE", "MAX_EXCURSION", "check_label", "sample_truth"]

#: Effect labels (``"none"`` is the control), in the order of :mod:`lagsplat.diagnose.effects`.
EFFECTS = (
    "none",
    "coulomb",
    "quadratic_drag",
    "end_stop",
    "cubic_stiffness",
    "periodic_force",
    "drift",
    "actuation_delay",
    "missing_dof",
)
#: Simulated systems.
SYSTEMS = ("pendulum", "cart")

#: Nominal amplitude ``A``: rad (pendulum), frame widths (cart).
NOMINAL_AMPLITUDE = {"pendulum": math.radians(20.0), "cart": 0.25}
#: Largest excursion the pictures accept: rad, frame widths.
MAX_EXCURSION = {"pendulum": math.radians(35.0), "cart": 0.35}


def check_label(system: str, effect: str) -> None:
    """Raise ``ValueError`` unless ``system`` is one of :data:`SYSTEMS` and ``effect`` one of :data:`EFFECTS`."""
    if system not in SYSTEMS:
        raise ValueError(f"system must be one of {SYSTEMS}, got {system!r}")
    if effect not in EFFECTS:
        raise ValueError(f"effect must be one of {EFFECTS}, got {effect!r}")


def _rng(seed: int, system: str, effect: str) -> np.random.Generator:
    """Generator seeded by ``(seed, system, effect)`` (stable across Python runs)."""
    return np.random.default_rng([int(seed), zlib.crc32(system.encode()), zlib.crc32(effect.encode())])


def sample_truth(system: str, effect: str, seed: int = 0, actuated: bool | None = None) -> dict[str, Any]:
    """The physical parameters of one clip, drawn from ``(seed, system, effect)``.

    Args:
        system: ``"pendulum"`` or ``"cart"``.
        effect: one of :data:`EFFECTS`.
        seed: integer seed; two seeds give two different systems with the same effect.
        actuated: drive the system with a logged input ``u``; ``None`` means
            "only for ``actuation_delay``", which requires it.

    Returns:
        ``{"system", "effect", "f0_hz", "zeta", "amplitude", "actuated", "effect_params": {...}}``
        (plus ``"actuation"``: gain and input sinusoids, when actuated).

    Raises:
        ValueError: on an unknown system / effect, or ``actuation_delay`` without actuation.
    """
    check_label(system, effect)
    act = effect == "actuation_delay" if actuated is None else bool(actuated)
    if effect == "actuation_delay" and not act:
        raise ValueError("the actuation_delay effect needs an actuated clip (actuated=True)")
    rng = _rng(seed, system, effect)
    f0 = float(rng.uniform(0.6, 1.0))
    zeta = float(rng.uniform(0.004, 0.012))
    A = NOMINAL_AMPLITUDE[system]
    w0 = 2 * math.pi * f0
    p: dict[str, Any] = {}
    if effect == "coulomb":
        kappa = float(rng.uniform(0.006, 0.012))
        p = {"kappa": kappa, "mu": kappa * w0**2 * A, "v_s": 0.002 * w0 * A}
    elif effect == "quadratic_drag":
        kappa = float(rng.uniform(0.03, 0.05))
        p = {"kappa": kappa, "c2": kappa / A}
    elif effect == "end_stop":
        side = 1.0 if rng.uniform() < 0.5 else -1.0
        p = {"side": side, "x_stop": side * float(rng.uniform(0.55, 0.7)) * A, "k_ratio": float(rng.uniform(15.0, 30.0))}
    elif effect == "cubic_stiffness":
        sign = 1.0 if int(seed) % 2 == 0 else -1.0
        eps = sign * float(rng.uniform(0.2, 0.35))
        p = {"eps": eps, "kind": "hardening" if eps > 0 else "softening", "k3_over_k1": eps / A**2}
    elif effect == "periodic_force":
        # off resonance and off the 2nd / 3rd harmonics (where a residual is read as a distortion of the motion)
        ratio = float(rng.uniform(2.2, 2.7)) if int(seed) % 2 == 0 else float(rng.uniform(0.35, 0.55))
        p = {"kappa": float(rng.uniform(0.05, 0.1)), "f_hz": ratio * f0, "phase": float(rng.uniform(0, 2 * math.pi))}
        p["amplitude"] = p["kappa"] * w0**2 * A
    elif effect == "drift":
        if int(seed) % 2 == 0:
            s = 1.0 if rng.uniform() < 0.5 else -1.0
            p = {"kind": "stiffness", "alpha": s * float(rng.uniform(0.2, 0.3))}
        else:
            p = {"kind": "damping", "zeta_start": 0.003, "zeta_end": float(rng.uniform(0.025, 0.035))}
    elif effect == "actuation_delay":
        p = {"tau_s": float(rng.uniform(0.1, 0.2))}
    elif effect == "missing_dof":
        ratio = float(rng.uniform(1.45, 1.8)) if int(seed) % 2 == 0 else float(rng.uniform(2.2, 2.6))  # off the harmonics
        p = {"f2_over_f0": ratio, "zeta2": float(rng.uniform(0.008, 0.02))}
        if system == "cart":
            p.update({"m2": float(rng.uniform(0.3, 0.5)), "mode2_share": float(rng.uniform(0.25, 0.4))})
        else:
            mu = float(rng.uniform(0.05, 0.1))
            p.update({"mass_ratio": mu, "pivot_amp": float(rng.uniform(0.06, 0.1))})
            # the pivot spring is tuned so that the *coupled* small-angle modes have the drawn ratio
            p["pivot_over_f0"] = _pivot_ratio_for(ratio, mu)
            p["f_modes_hz"] = [f * f0 for f in _pivot_modes(p["pivot_over_f0"], mu)]
    out: dict[str, Any] = {
        "system": system,
        "effect": effect,
        "f0_hz": f0,
        "zeta": zeta,
        "amplitude": A,
        "actuated": act,
        "effect_params": p,
    }
    if act:
        n_c = 3  # one input component in each band, away from the resonance at f0
        freqs = f0 * np.array([rng.uniform(0.25, 0.4), rng.uniform(0.55, 0.7), rng.uniform(1.5, 1.9)])
        amps = rng.uniform(0.5, 1.0, n_c)
        amps /= amps.sum()
        out["actuation"] = {
            "gain": float(rng.uniform(0.25, 0.4)) * w0**2 * A,  # acceleration per unit u
            "freqs_hz": freqs.tolist(),
            "amps": amps.tolist(),
            "phases": rng.uniform(0, 2 * math.pi, n_c).tolist(),
        }
    return out


def _pivot_modes(r_p: float, mu: float) -> tuple[float, float]:
    """Small-angle modal frequencies (units of ``f0``) of the pendulum on a sprung pivot (:func:`_rhs_pivot`).

    Linearised, ``[[1, 1], [mu, 1]] (theta, X)'' = -diag(1, r_p^2) (theta, X)`` in units of ``w0``.
    """
    M = np.array([[1.0, 1.0], [mu, 1.0]])
    lam = np.sort(np.linalg.eigvals(np.linalg.solve(M, np.diag([1.0, r_p * r_p]))).real)
    return float(np.sqrt(lam[0])), float(np.sqrt(lam[1]))


def _pivot_ratio_for(ratio: float, mu: float) -> float:
    """Pivot frequency ``wp / w0 >= 1`` giving the coupled mode ratio ``f_2 / f_1 = ratio`` (the ratio grows with ``wp`` there)."""
    from scipy.optimize import brentq

    def gap(r_p: float) -> float:
        a, b = _pivot_modes(r_p, mu)
        return b / a - ratio

    return float(brentq(gap, 1.0, 50.0))
