"""The diagnosed effects as torch generalized forces: :class:`EffectTerm` and one class per effect with a Stage-2 term.

Each term is a module ``f_eff(q, qdot, t)`` ``[B,d]`` along a fixed latent
direction, added to the right-hand side of the Euler-Lagrange equation (paper
Eq. 7) by :class:`~lagsplat.diagnose.terms.AugmentedLagrangian`. The forms keep
the guarantees of paper App. A.2:

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
  stiffness added never below ``-k_floor``.

:meth:`EffectTerm.spec` records a term's constructor arguments at their
current values and :func:`term_from_spec` rebuilds it (a refit checkpoint,
:mod:`lagsplat.diagnose.refit_io`); :func:`~lagsplat.diagnose.terms.build_term`
initialises one from a diagnosis.
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
    "term_from_spec",
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
        """``-mu tanh(sdot / v_s)`` ``[B]``."""
        _, v = self.coords(q, qdot)
        return -self.mu * torch.tanh(v / self.v_s)

    def spec(self):
        """Constructor arguments at the current values (``mu``, ``v_s``)."""
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
        """``-c2 |sdot| sdot`` ``[B]``."""
        _, v = self.coords(q, qdot)
        return -self.c2 * v.abs() * v

    def spec(self):
        """Constructor arguments at the current values (``c2``)."""
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
        """``1/2 k relu(side (s - s_stop))^2`` ``[B]``."""
        s = q @ self.e.to(q.dtype)
        return 0.5 * self.k * torch.relu(self.side * (s - self.s_stop)) ** 2

    def magnitude(self, q, qdot, t):
        """``-k side relu(side (s - s_stop))`` ``[B]``."""
        s, _ = self.coords(q, qdot)
        return -self.k * self.side * torch.relu(self.side * (s - self.s_stop))

    def spec(self):
        """Constructor arguments at the current values (``k``, ``s_stop``, ``side``)."""
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
        """The hardening quartic or the saturating softening form ``[B]`` (class docstring)."""
        x = q @ self.e.to(q.dtype) - self.s0
        hard = 0.25 * torch.relu(self.k3) * x**4
        soft = -0.25 * torch.relu(-self.k3) * self.s_c**4 * torch.log1p((x / self.s_c) ** 4)
        return hard + soft

    def magnitude(self, q, qdot, t):
        """``-dV_eff/ds`` ``[B]``: ``-k3 x^3`` near ``s0``, saturating when softening."""
        x, _ = self.coords(q, qdot)
        x = x - self.s0
        return -torch.relu(self.k3) * x**3 + torch.relu(-self.k3) * x**3 / (1.0 + (x / self.s_c) ** 4)

    def spec(self):
        """Constructor arguments at the current values (``k3``, ``s0``, ``s_c``)."""
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
        """``a cos(2 pi f t) + b sin(2 pi f t)`` ``[B]`` (``t`` clip time, s)."""
        w = 2 * math.pi * self.f_hz.to(q.dtype) * t.to(q.dtype)
        return self.ab[0] * torch.cos(w) + self.ab[1] * torch.sin(w)

    def spec(self):
        """Constructor arguments at the current values (``f_hz``, ``a``, ``b``)."""
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
        """``-(k(t) (s - s0) + c(t) sdot)`` ``[B]`` with the clamped rates."""
        s, v = self.coords(q, qdot)
        dt = t.to(q.dtype) - self.t_ref
        k = torch.clamp(self.rates[0] * dt, min=-self.k_floor)
        c = torch.clamp(self.rates[1] * dt, min=-self.c_floor)
        return -(k * (s - self.s0) + c * v)

    def spec(self):
        """Constructor arguments at the current values (rates, reference time, centre, clamps)."""
        return {
            **super().spec(), "k_rate": float(self.rates[0].detach()), "c_rate": float(self.rates[1].detach()), "t_ref": float(self.t_ref),
            "s0": float(self.s0), "c_floor": float(self.c_floor), "k_floor": float(self.k_floor),
        }  # fmt: skip

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
