"""Winning effects as torch terms for the Stage-2 refit: the augmented model, the input channels, the initial term.

Each diagnosed effect becomes a generalized-force module ``f_eff(q, qdot, t)``
``[B,d]`` (:mod:`lagsplat.diagnose.effect_terms`, where the forms and their
energy guarantees of paper App. A.2 are listed) that is added to the
right-hand side of the Euler-Lagrange equation (paper Eq. 7) by
:class:`AugmentedLagrangian`. Two effects have no force term:

* an **actuation delay** is not a force but a shift of the logged input:
  :func:`delay_actuation` returns the input the model should see;
* a **missing degree of freedom** has no force form: the remedy is one more
  latent dimension (Stage 1 with ``d + 1``); :func:`build_term` says so.

Time enters through an extra last channel of the actuation ``u`` (seconds):
:class:`AugmentedLagrangian` with ``time_channel=True`` splits it off, so the
integrators and the Stage-2 loop need no change (``u`` at the start and end of
each Verlet step is exactly the time there, :func:`with_time_channel`).

How Stage 2 adds them (proposed hook, not wired here)
-----------------------------------------------------
``train_stage2`` builds and initialises the plain model, then (new keyword
``terms: nn.ModuleList | None``)::

    model = cfg.build(d, n_u_base, inertia); ...; model.init_energy_scales(...)
    if terms:  # after the gauge is fixed, so the terms share its units
        model = AugmentedLagrangian(model, terms, time_channel=any(t.needs_time for t in terms))

with the chart passed through :func:`with_time_channel` when a term needs
time and ``n_u_base = chart.n_u - 1`` then. Everything else (windows, Verlet
steps, rollouts for model selection, evaluation) goes through
``model.acceleration(q, qdot, f_ext, u)`` and works unchanged;
``save_stage2`` would store ``[term.spec() for term in terms]`` next to the
state dict so that ``load_stage2`` can rebuild them
(:func:`~lagsplat.diagnose.effect_terms.term_from_spec`). Coefficients
start at the diagnosed values (:func:`build_term`), which are in the same
generalized-force units as long as the chart and the Stage-2 settings (hence
the gauge ``s_M`` fixed from the training frequency) are the same.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from torch import Tensor, nn

from lagsplat.diagnose.effect_terms import (
    CoulombFriction,
    CubicStiffness,
    EffectTerm,
    EndStop,
    PeriodicForce,
    QuadraticDrag,
    StiffnessDampingDrift,
)

__all__ = [
    "AugmentedLagrangian",
    "build_term",
    "delay_actuation",
    "with_time_channel",
]


class AugmentedLagrangian(nn.Module):
    """A fitted model plus effect terms, with the same ``acceleration`` interface (paper Eq. 7 + ``f_eff``).

    ``acceleration(q, qdot, f_ext, u) = base.acceleration(q, qdot, f_ext + sum_k f_k(q, qdot, t), u_base)``:
    the terms enter exactly where an external generalized force does. With
    ``time_channel=True`` the last column of ``u`` is the clip time (s) and is
    removed before ``u`` reaches the base model (``None`` if nothing is left).

    Energies: :meth:`potential` adds the conservative terms' ``V_eff`` to the
    base potential, so ``T + potential`` is the energy that the dissipative terms
    can only decrease (App. A.2).

    Args:
        base: the Lagrangian (or any model with ``acceleration``).
        terms: the :class:`EffectTerm` modules.
        time_channel: read the time from ``u[:, -1]``.

    Raises:
        ValueError: if a term needs time and ``time_channel`` is off.
    """

    def __init__(self, base: nn.Module, terms: Sequence[EffectTerm], time_channel: bool = False) -> None:
        super().__init__()
        self.base = base
        self.terms = nn.ModuleList(terms)
        self.time_channel = bool(time_channel)
        if any(t.needs_time for t in self.terms) and not self.time_channel:
            raise ValueError("a term depends on time: build AugmentedLagrangian(..., time_channel=True) and add the time channel to u")

    @property
    def d(self) -> int:
        """Latent dimension."""
        return int(self.base.d)

    @property
    def n_u(self) -> int:
        """Actuation channels of the base model (the time channel not counted)."""
        return int(getattr(self.base, "n_u", 0))

    def split_u(self, u: Tensor | None) -> tuple[Tensor | None, Tensor | None]:
        """``(u_base [B,n_u] | None, t [B] | None)``."""
        if not self.time_channel:
            return u, None
        if u is None:
            raise ValueError("time_channel=True but no u (with the time as last column) was given")
        ub = u[:, :-1] if u.shape[1] > 1 else None
        return ub, u[:, -1]

    def effect_force(self, q: Tensor, qdot: Tensor, t: Tensor | None) -> Tensor:
        """``sum_k f_k [B,d]``."""
        f = q.new_zeros(q.shape)
        for term in self.terms:
            f = f + term(q, qdot, t)
        return f

    def acceleration(self, q: Tensor, qdot: Tensor, f_ext: Tensor | None = None, u: Tensor | None = None) -> Tensor:
        """``qddot [B,d]`` of the base model under ``f_ext + f_eff`` (see the class docstring)."""
        ub, t = self.split_u(u)
        f = self.effect_force(q, qdot, t)
        f = f if f_ext is None else f + f_ext
        if ub is None:
            return self.base.acceleration(q, qdot, f)
        return self.base.acceleration(q, qdot, f, u=ub)

    def mass_matrix(self, q: Tensor) -> Tensor:
        """The base model's inertia ``[B,d,d]``."""
        return self.base.mass_matrix(q)

    def potential(self, q: Tensor) -> Tensor:
        """``V(q) + sum V_eff(q)`` ``[B]``."""
        V = self.base.potential(q)
        for term in self.terms:
            V = V + term.potential(q)
        return V

    def energy(self, q: Tensor, qdot: Tensor) -> Tensor:
        """``T + V + sum V_eff`` ``[B]`` (the Lyapunov function of a free rollout)."""
        T, _, _ = self.base.energies(q, qdot)
        return T + self.potential(q)


def delay_actuation(u: np.ndarray, t: np.ndarray, tau_s: float) -> np.ndarray:
    """The input a model should see when the logged one acts ``tau_s`` seconds late: ``u(t - tau)``.

    Linear interpolation in ``t`` (the first value before the start).

    Args:
        u: ``[T,n_u]`` logged actuation; t: ``[T]`` times (s, increasing); tau_s: delay (>= 0).

    Returns:
        float32 ``[T,n_u]``.

    Raises:
        ValueError: on a negative delay or mismatched shapes.
    """
    u = np.asarray(u, np.float64)
    t = np.asarray(t, np.float64)
    if tau_s < 0:
        raise ValueError(f"tau_s must be >= 0, got {tau_s!r}")
    if u.ndim != 2 or len(u) != len(t):
        raise ValueError(f"u must be [T,n_u] with T = len(t) = {len(t)}, got {u.shape}")
    return np.stack([np.interp(t - tau_s, t, u[:, j]) for j in range(u.shape[1])], 1).astype(np.float32) if u.shape[1] else u.astype(np.float32)


def with_time_channel(chart: Any) -> Any:
    """A copy of a :class:`~lagsplat.chart.Chart` whose ``u`` has the frame time (s) as an extra last column."""
    import copy

    out = copy.copy(chart)
    out.u = np.concatenate([np.asarray(chart.u, np.float32).reshape(len(chart.t), -1), np.asarray(chart.t, np.float32)[:, None]], 1)
    return out

def build_term(fit: Any, model: Any | None = None, c0: float | None = None) -> EffectTerm | None:
    """The refit term of a diagnosed effect, initialised at the diagnosed coefficients.

    Args:
        fit: a :class:`~lagsplat.diagnose.diagnosis.CandidateFit` (``effect``, ``params``,
            ``direction``, ``coef``, ``interpretation``).
        model: the fitted model (its ``c0`` sets the drift's damping clamp; optional).
        c0: dissipation floor, overrides ``model.c0`` (default 1).

    In-class effects (cubic stiffness, end stop) are diagnosed against the
    model's linearisation, so their coefficients are the *total* ones: the right
    start for a Stage-2 refit from scratch. To fine-tune the already fitted
    model instead, start from the part it lacks,
    ``coef - interpretation["model_carries"]``.

    Returns:
        The :class:`EffectTerm`, or ``None`` for effects that are not a force term:
        ``actuation_delay`` (use :func:`delay_actuation` with ``fit.params["tau_s"]``)
        and ``missing_dof`` (add a latent dimension).

    Raises:
        KeyError: on an unknown effect name.
    """
    e = np.asarray(fit.direction, np.float64)
    c = np.asarray(fit.coef, np.float64)
    p = fit.params
    interp = getattr(fit, "interpretation", {}) or {}
    if fit.effect == "coulomb":
        return CoulombFriction(e, max(c[0], 1e-6), p["v_s"])
    if fit.effect == "quadratic_drag":
        return QuadraticDrag(e, max(c[0], 1e-6))
    if fit.effect == "end_stop":
        return EndStop(e, max(c[0], 1e-6), p["s_stop"], p["side"])
    if fit.effect == "cubic_stiffness":
        A = float(interp.get("amplitude", 1.0))
        s0 = float(interp.get("s_bar", p.get("s_bar", 0.0)))
        return CubicStiffness(e, c[0], s0, 3.0 * max(A, 1e-6))
    if fit.effect == "periodic_force":
        return PeriodicForce(e, p["f_hz"], c[0], c[1])
    if fit.effect == "drift":
        floor = float(c0 if c0 is not None else getattr(model, "c0", 1.0))
        k_floor = float(interp.get("k_model", 0.0)) * 0.5
        return StiffnessDampingDrift(e, c[0], c[1], float(interp.get("t_bar", 0.0)), float(interp.get("s_bar", 0.0)), 0.5 * floor, k_floor)
    if fit.effect in ("actuation_delay", "missing_dof"):
        return None
    raise KeyError(f"no refit term for effect {fit.effect!r}")
