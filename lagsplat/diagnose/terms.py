"""Winning effects as torch terms for the Stage-2 refit.

Each diagnosed effect becomes a generalized-force module ``f_eff(q, qdot, t)``
``[B,d]`` that is added to the right-hand side of the Euler-Lagrange equation
(paper Eq. 7). The forms keep the guarantees of paper App. A.2:

* **dissipative** terms (:class:`CoulombFriction`, :class:`QuadraticDrag`) satisfy
  ``qdot^T f <= 0`` for every state by construction (non-negative coefficients
  through a softplus; ``tanh`` and ``|s| s`` are odd and increasing), so the
  energy balance ``dE/dt = f_ext^T qdot - qdot^T C qdot + qdot^T f_eff`` still
  gives ``dE/dt <= -c0 |qdot|^2`` on a free rollout;
* **conservative** terms (:class:`EndStop`, :class:`CubicStiffness`) derive
  from a potential ``V_eff(q)`` that is added to ``V``: the end stop's one-sided
  penalty ``1/2 k relu(side (s - s_stop))^2`` and the hardening quartic are
  convex and non-negative; the softening form
  ``-|k3| s_c^4 / 4 log(1 + (s / s_c)^4)`` is cubic near the rest state and
  grows only logarithmically, so ``V + V_eff`` stays coercive (the quadratic
  floor of ``V`` dominates) and the free rollout still settles (LaSalle);
* **time-dependent** terms: :class:`PeriodicForce` is a bounded input (the
  response stays bounded: the balance with a bounded ``f_ext``);
  :class:`StiffnessDampingDrift` varies the stiffness and damping linearly in
  time, each clamped so that the damping added never falls below ``-c_floor``
  (pass ``c_floor < c0`` to keep ``C + c(t) I >= (c0 - c_floor) I``) and the
  stiffness added never below ``-k_floor``;
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
state dict so that ``load_stage2`` can rebuild them (:func:`term_from_spec`). Coefficients
start at the diagnosed values (:func:`build_term`), which are in the same
generalized-force units as long as the chart and the Stage-2 settings (hence
the gauge ``s_M`` fixed from the training frequency) are the same.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor, nn

__all__ = [
    "EffectTerm",
    "CoulombFriction",
    "QuadraticDrag",
    "EndStop",
    "CubicStiffness",
    "PeriodicForce",
    "StiffnessDampingDrift",
    "AugmentedLagrangian",
    "build_term",
    "term_from_spec",
    "delay_actuation",
    "with_time_channel",
]


def _inv_softplus(x: float) -> float:
    x = max(float(x), 1e-8)
    return x + math.log(-math.expm1(-x))


class EffectTerm(nn.Module):
    """Base class: a generalized force along a fixed unit latent direction ``e`` ``[d]``.

    Subclasses implement :meth:`magnitude` (the scalar force on ``s = e^T q``);
    :meth:`forward` returns ``f = e * magnitude`` ``[B,d]``.

    Attributes:
        kind: ``"dissipative"``, ``"conservative"`` or ``"time"``.
        needs_time: whether :meth:`forward` uses ``t``.

    Raises:
        ValueError: if ``direction`` is zero or not finite.
    """

    kind = "force"
    needs_time = False

    def __init__(self, direction: Sequence[float] | np.ndarray | Tensor) -> None:
        super().__init__()
        e = torch.as_tensor(np.asarray(direction, np.float64), dtype=torch.float32).reshape(-1)
        n = float(torch.linalg.norm(e))
        if not (math.isfinite(n) and n > 0):
            raise ValueError(f"direction must be a non-zero finite vector, got {direction!r}")
        self.register_buffer("e", e / n)

    @property
    def d(self) -> int:
        """Latent dimension."""
        return int(self.e.shape[0])

    def coords(self, q: Tensor, qdot: Tensor) -> tuple[Tensor, Tensor]:
        """``(s, sdot)`` ``[B]``."""
        e = self.e.to(q.dtype)
        return q @ e, qdot @ e

    def magnitude(self, q: Tensor, qdot: Tensor, t: Tensor | None) -> Tensor:
        """Scalar generalized force on ``s``, ``[B]``."""
        raise NotImplementedError

    def forward(self, q: Tensor, qdot: Tensor, t: Tensor | None = None) -> Tensor:
        """Generalized force ``[B,d]`` at ``q, qdot [B,d]`` and time ``t [B]`` (s)."""
        if self.needs_time and t is None:
            raise ValueError(f"{type(self).__name__} depends on time but no t was given (use AugmentedLagrangian(time_channel=True))")
        return self.magnitude(q, qdot, t)[:, None] * self.e.to(q.dtype)[None, :]

    def potential(self, q: Tensor) -> Tensor:
        """``V_eff(q) [B]`` of a conservative term (zero otherwise)."""
        return q.new_zeros(q.shape[0])

    def spec(self) -> dict[str, Any]:
        """Constructor arguments at the current values (to save next to a checkpoint)."""
        return {"class": type(self).__name__, "direction": self.e.tolist()}


class CoulombFriction(EffectTerm):
    """Dry friction with a smooth sign: ``f = -mu tanh(sdot / v_s) e``, ``mu = softplus(raw) >= 0``.

    ``qdot^T f = -mu sdot tanh(sdot / v_s) <= 0`` for every state (paper App. A.2).

    Args:
        direction: ``[d]``; mu: initial level (> 0, generalized-force units);
        v_s: smoothing velocity (fixed, latent units per second, > 0).
    """

    kind = "dissipative"

    def __init__(self, direction, mu: float, v_s: float) -> None:
        super().__init__(direction)
        if not v_s > 0:
            raise ValueError(f"v_s must be positive, got {v_s!r}")
        self.raw = nn.Parameter(torch.tensor(_inv_softplus(mu)))
        self.register_buffer("v_s", torch.tensor(float(v_s)))

    @property
    def mu(self) -> Tensor:
        """Friction level ``>= 0``."""
        return F.softplus(self.raw)

    def magnitude(self, q, qdot, t):
        _, v = self.coords(q, qdot)
        return -self.mu * torch.tanh(v / self.v_s)

    def spec(self):
        return {**super().spec(), "mu": float(self.mu.detach()), "v_s": float(self.v_s)}


class QuadraticDrag(EffectTerm):
    """Quadratic drag ``f = -c2 |sdot| sdot e``, ``c2 = softplus(raw) >= 0``; ``qdot^T f = -c2 |sdot|^3 <= 0``.

    Args:
        direction: ``[d]``; c2: initial coefficient (> 0).
    """

    kind = "dissipative"

    def __init__(self, direction, c2: float) -> None:
        super().__init__(direction)
        self.raw = nn.Parameter(torch.tensor(_inv_softplus(c2)))

    @property
    def c2(self) -> Tensor:
        """Drag coefficient ``>= 0``."""
        return F.softplus(self.raw)

    def magnitude(self, q, qdot, t):
        _, v = self.coords(q, qdot)
        return -self.c2 * v.abs() * v

    def spec(self):
        return {**super().spec(), "c2": float(self.c2.detach())}


class EndStop(EffectTerm):
    """One-sided penalty contact: ``V_eff = 1/2 k relu(side (s - s_stop))^2``, ``f = -dV_eff/dq``.

    Convex, non-negative, zero on the free side; ``k = softplus(raw) >= 0``.

    Args:
        direction: ``[d]``; k: initial stiffness (> 0); s_stop: stop position on ``s``;
        side: ``+1`` (stop above ``s_stop``) or ``-1`` (below).
    """

    kind = "conservative"

    def __init__(self, direction, k: float, s_stop: float, side: float) -> None:
        super().__init__(direction)
        if side not in (1, -1, 1.0, -1.0):
            raise ValueError(f"side must be +1 or -1, got {side!r}")
        self.raw = nn.Parameter(torch.tensor(_inv_softplus(k)))
        self.register_buffer("s_stop", torch.tensor(float(s_stop)))
        self.register_buffer("side", torch.tensor(float(side)))

    @property
    def k(self) -> Tensor:
        """Stop stiffness ``>= 0``."""
        return F.softplus(self.raw)

    def potential(self, q):
        s = q @ self.e.to(q.dtype)
        return 0.5 * self.k * torch.relu(self.side * (s - self.s_stop)) ** 2

    def magnitude(self, q, qdot, t):
        s, _ = self.coords(q, qdot)
        return -self.k * self.side * torch.relu(self.side * (s - self.s_stop))

    def spec(self):
        return {**super().spec(), "k": float(self.k.detach()), "s_stop": float(self.s_stop), "side": float(self.side)}


class CubicStiffness(EffectTerm):
    """Hardening (``k3 > 0``) or softening (``k3 < 0``) stiffness about ``s0``, from a potential.

    ``V_eff = k3 x^4 / 4`` for ``k3 >= 0`` and ``V_eff = k3 s_c^4 / 4 log(1 + (x / s_c)^4)``
    for ``k3 < 0`` (``x = s - s0``): both give the force ``-k3 x^3`` near ``s0``;
    the softening one saturates (``|f| -> 0`` beyond ``s_c``), so ``V + V_eff`` stays
    coercive and bounded below (see the module docstring). ``k3`` is free.

    Args:
        direction: ``[d]``; k3: initial coefficient; s0: centre on ``s``;
        s_c: saturation scale of the softening form (> 0; choose ~3x the amplitude).
    """

    kind = "conservative"

    def __init__(self, direction, k3: float, s0: float, s_c: float) -> None:
        super().__init__(direction)
        if not s_c > 0:
            raise ValueError(f"s_c must be positive, got {s_c!r}")
        self.k3 = nn.Parameter(torch.tensor(float(k3)))
        self.register_buffer("s0", torch.tensor(float(s0)))
        self.register_buffer("s_c", torch.tensor(float(s_c)))

    def potential(self, q):
        x = q @ self.e.to(q.dtype) - self.s0
        hard = 0.25 * torch.relu(self.k3) * x**4
        soft = -0.25 * torch.relu(-self.k3) * self.s_c**4 * torch.log1p((x / self.s_c) ** 4)
        return hard + soft

    def magnitude(self, q, qdot, t):
        x, _ = self.coords(q, qdot)
        x = x - self.s0
        return -torch.relu(self.k3) * x**3 + torch.relu(-self.k3) * x**3 / (1.0 + (x / self.s_c) ** 4)

    def spec(self):
        return {**super().spec(), "k3": float(self.k3.detach()), "s0": float(self.s0), "s_c": float(self.s_c)}


class PeriodicForce(EffectTerm):
    """Unlogged periodic force ``f = (a cos 2 pi f t + b sin 2 pi f t) e`` (``t`` clip time, s).

    Args:
        direction: ``[d]``; f_hz: frequency (fixed, > 0); a, b: initial amplitudes.
    """

    kind = "time"
    needs_time = True

    def __init__(self, direction, f_hz: float, a: float, b: float) -> None:
        super().__init__(direction)
        if not f_hz > 0:
            raise ValueError(f"f_hz must be positive, got {f_hz!r}")
        self.register_buffer("f_hz", torch.tensor(float(f_hz)))
        self.ab = nn.Parameter(torch.tensor([float(a), float(b)]))

    def magnitude(self, q, qdot, t):
        w = 2 * math.pi * self.f_hz.to(q.dtype) * t.to(q.dtype)
        return self.ab[0] * torch.cos(w) + self.ab[1] * torch.sin(w)

    def spec(self):
        return {**super().spec(), "f_hz": float(self.f_hz), "a": float(self.ab[0].detach()), "b": float(self.ab[1].detach())}


class StiffnessDampingDrift(EffectTerm):
    """Slow linear drift: ``f = -(k(t) (s - s0) + c(t) sdot) e`` with ``k(t) = k_rate (t - t_ref)``, ``c(t) = c_rate (t - t_ref)``.

    Clamped: ``c(t) >= -c_floor`` and ``k(t) >= -k_floor``, so the total damping
    stays ``>= c0 - c_floor`` (choose ``c_floor < c0``) and the stiffness added
    cannot make the potential lose its minimum (choose ``k_floor`` below the
    model's stiffness along ``e``).

    Args:
        direction: ``[d]``; k_rate, c_rate: initial rates (per second); t_ref: reference time, s;
        s0: centre on ``s``; c_floor, k_floor: clamps (>= 0).
    """

    kind = "time"
    needs_time = True

    def __init__(self, direction, k_rate: float, c_rate: float, t_ref: float, s0: float, c_floor: float, k_floor: float) -> None:
        super().__init__(direction)
        if c_floor < 0 or k_floor < 0:
            raise ValueError(f"c_floor and k_floor must be >= 0, got {c_floor!r}, {k_floor!r}")
        self.rates = nn.Parameter(torch.tensor([float(k_rate), float(c_rate)]))
        for name, v in (("t_ref", t_ref), ("s0", s0), ("c_floor", c_floor), ("k_floor", k_floor)):
            self.register_buffer(name, torch.tensor(float(v)))

    def magnitude(self, q, qdot, t):
        s, v = self.coords(q, qdot)
        dt = t.to(q.dtype) - self.t_ref
        k = torch.clamp(self.rates[0] * dt, min=-self.k_floor)
        c = torch.clamp(self.rates[1] * dt, min=-self.c_floor)
        return -(k * (s - self.s0) + c * v)

    def spec(self):
        return {
            **super().spec(), "k_rate": float(self.rates[0].detach()), "c_rate": float(self.rates[1].detach()), "t_ref": float(self.t_ref),
            "s0": float(self.s0), "c_floor": float(self.c_floor), "k_floor": float(self.k_floor),
        }  # fmt: skip


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


def term_from_spec(spec: dict[str, Any]) -> EffectTerm:
    """Rebuild a term from :meth:`EffectTerm.spec` (e.g. stored next to a Stage-2 checkpoint).

    Raises:
        KeyError: if ``spec["class"]`` is not one of the terms of this module.
    """
    classes = {c.__name__: c for c in (CoulombFriction, QuadraticDrag, EndStop, CubicStiffness, PeriodicForce, StiffnessDampingDrift)}
    name = spec.get("class")
    if name not in classes:
        raise KeyError(f"unknown effect term class {name!r}; known: {sorted(classes)}")
    return classes[name](**{k: v for k, v in spec.items() if k != "class"})


def build_term(fit: Any, model: Any | None = None, c0: float | None = None) -> EffectTerm | None:
    """The refit term of a diagnosed effect, initialised at the diagnosed coefficients.

    Args:
        fit: a :class:`~lagsplat.diagnose.select.CandidateFit` (``effect``, ``params``,
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
