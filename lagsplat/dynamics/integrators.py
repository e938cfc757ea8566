"""Symplectic time stepping of ``acceleration(q, qdot, f_ext)`` (paper §3.3-3.4).

Only the acceleration interface of the model is used, so the same integrator
serves training, rollouts, forces and evaluation.
"""

from __future__ import annotations

from typing import Callable, Protocol

import numpy as np
import torch
from torch import Tensor

from lagsplat.timeseries import forward_difference_velocity

__all__ = ["HasAcceleration", "verlet_step", "rollout", "fast_unavailable", "initial_state", "actuation_schedule"]

Force = Callable[[float], Tensor] | Tensor | None


class HasAcceleration(Protocol):
    """Anything exposing ``acceleration(q [B,d], qdot [B,d], f_ext [B,d] | None) -> [B,d]``."""

    def acceleration(self, q: Tensor, qdot: Tensor, f_ext: Tensor | None = None) -> Tensor: ...


def _force_at(f: Force, t: float) -> Tensor | None:
    if f is None or isinstance(f, Tensor):
        return f
    return f(t)


def _accel(model: HasAcceleration, q: Tensor, qdot: Tensor, f: Tensor | None, u: Tensor | None) -> Tensor:
    if u is None:
        return model.acceleration(q, qdot, f)
    return model.acceleration(q, qdot, f, u=u)  # type: ignore[call-arg]


def verlet_step(
    model: HasAcceleration, q: Tensor, qdot: Tensor, h: float, f_ext: Force = None, t: float = 0.0, u: Force = None
) -> tuple[Tensor, Tensor]:
    """One velocity-Verlet step of size ``h`` seconds (paper Eq. 8).

    ``a1 = a(q, qdot, f(t))``; ``v_half = qdot + h/2 a1``; ``q1 = q + h v_half``;
    ``a2 = a(q1, v_half, f(t + h))``; ``qdot1 = v_half + h/2 a2``. The second
    force evaluation uses the half-step velocity for the velocity-dependent
    terms, as in the reference implementation. For a
    conservative model this is the symplectic, second-order Stormer-Verlet
    scheme; the dissipative terms are integrated to first order (the error
    halves with ``h``, tests/test_dynamics.py).

    Args:
        model: exposes ``acceleration``.
        q, qdot: ``[B,d]``.
        h: step in seconds.
        f_ext: ``[B,d]`` constant generalized force, a callable ``t -> [B,d]``, or ``None``.
        t: time at the start of the step, seconds.
        u: measured actuation ``[B,n_u]``, a callable ``t -> [B,n_u]``, or
            ``None``; passed to ``model.acceleration(..., u=...)`` (paper Eq. 6).

    Returns:
        ``(q1, qdot1)``, each ``[B,d]``; differentiable when the model is.
    """
    a1 = _accel(model, q, qdot, _force_at(f_ext, t), _force_at(u, t))
    v_half = qdot + 0.5 * h * a1
    q1 = q + h * v_half
    a2 = _accel(model, q1, v_half, _force_at(f_ext, t + h), _force_at(u, t + h))
    return q1, v_half + 0.5 * h * a2


def rollout(
    model: HasAcceleration,
    q0: Tensor,
    qdot0: Tensor,
    h: float,
    n_states: int,
    f_ext: Force = None,
    t0: float = 0.0,
    u: Force = None,
    fast: bool | None = None,
) -> tuple[Tensor, Tensor]:
    """Free (or forced) rollout with :func:`verlet_step`, no gradient.

    Args:
        model: exposes ``acceleration``.
        q0, qdot0: ``[B,d]`` initial state.
        h: step in seconds.
        n_states: number of states returned, the initial one included.
        f_ext, u: as in :func:`verlet_step` (callables receive absolute time ``t0 + i h``).
        t0: start time, seconds.
        fast: use the compiled path of :mod:`lagsplat.dynamics.fast` (same
            scheme, float64 inside, analytic gradients; much faster at batch 1: benchmarks/rollout.py,
            results/benchmarks/rollout.md).
            ``None`` (default): automatically when the model supports it
            (:func:`~lagsplat.dynamics.fast.supports_fast`: ``Lagrangian`` with
            ``"scalar"``/``"constant"``/``"learned"`` mass, any actuation), is in
            eval mode, the state is on the CPU and ``f_ext`` is ``None`` or a
            constant tensor (``u`` may be a tensor or a callable, sampled at each step). ``False``: always the torch
            path. ``True``: the compiled path, or ``ValueError`` if it cannot be used.

    Returns:
        ``(q [B,n_states,d], qdot [B,n_states,d])``, in ``q0``'s dtype. A
        trajectory that becomes non-finite keeps NaN from that step on (it is
        never silently frozen).

    Raises:
        ValueError: if ``fast=True`` and the compiled path cannot be used.
    """
    if fast is not False:
        why = fast_unavailable(model, q0, f_ext, u)
        if why is None:
            from lagsplat.dynamics.fast import cached_export, fast_rollout

            u_a, u_b = _actuation_samples(u, t0, h, n_states)
            q_np, v_np = fast_rollout(cached_export(model), q0, qdot0, h, n_states, f_ext, u_a, u_b)  # type: ignore[arg-type]
            return (
                torch.from_numpy(q_np).to(dtype=q0.dtype, device=q0.device),
                torch.from_numpy(v_np).to(dtype=q0.dtype, device=q0.device),
            )
        if fast:
            raise ValueError(f"fast=True but the compiled rollout cannot be used: {why}")
    qs, vs = [q0.detach()], [qdot0.detach()]
    q, v = q0.detach(), qdot0.detach()
    with torch.no_grad():  # no graph is recorded (the model's own derivatives are closed-form or enable grad locally)
        for i in range(n_states - 1):
            q, v = verlet_step(model, q, v, h, f_ext, t0 + i * h, u)
            qs.append(q)
            vs.append(v)
    return torch.stack(qs, 1), torch.stack(vs, 1)


def fast_unavailable(model: HasAcceleration, q0: Tensor, f_ext: Force, u: Force) -> str | None:
    """Why a rollout of ``model`` from ``q0`` under ``f_ext`` / ``u`` cannot take the compiled path (``None`` when it can):
    time-dependent forces, tensors off the CPU, training mode, or a model :mod:`lagsplat.dynamics.fast` does not support."""
    if f_ext is not None and not isinstance(f_ext, Tensor):
        return "f_ext is time-dependent (a callable)"
    if q0.device.type != "cpu" or (f_ext is not None and f_ext.device.type != "cpu"):
        return "tensors are not on the CPU"
    if getattr(model, "training", False):
        return "the model is in training mode"
    try:
        from lagsplat.dynamics.fast import unsupported_reason
    except ImportError as exc:  # numba missing
        return f"lagsplat.dynamics.fast unavailable ({exc})"
    return unsupported_reason(model)


def _actuation_samples(u: Force, t0: float, h: float, n_states: int) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The actuation at the two force evaluations of each step, ``[B, n_states-1, n_u]`` each (``None`` without one):
    a constant tensor at both; a callable at ``t0 + i h`` and ``t0 + (i+1) h``, as :func:`verlet_step` reads it."""
    if u is None:
        return None, None
    if isinstance(u, Tensor):
        a = u.detach().cpu().double().numpy()
        return a, a
    at = np.stack([np.asarray(_force_at(u, t0 + i * h).detach().cpu().double()) for i in range(max(n_states, 2))], 1)
    return at[:, : n_states - 1], at[:, 1:n_states]


def initial_state(q: np.ndarray, starts: np.ndarray, dt: float) -> tuple[Tensor, Tensor]:
    """Initial state ``(q0 [N,d], qdot0 [N,d])`` read off an encoded trajectory.

    Position at each start, velocity by the second-order forward difference
    over the next two frames (the reference code), the convention of every
    rollout that is scored or plotted.

    Args:
        q: ``[n,d]`` (smoothed) trajectory, frames ``dt`` seconds apart.
        starts: ``[N]`` start indices, each ``<= n - 3``.
        dt: frame interval, seconds.
    """
    v0 = forward_difference_velocity(np.stack([q[starts], q[starts + 1], q[starts + 2]]), dt)[0]
    return torch.as_tensor(q[starts], dtype=torch.float32), torch.as_tensor(v0, dtype=torch.float32)


def actuation_schedule(u: np.ndarray | None, dt: float):
    """Piecewise-linear actuation ``t -> [B,n_u]`` from per-frame samples ``u [B,n,n_u]`` (``t = 0`` at frame 0).

    Returns ``None`` when there is no actuation (``u`` is ``None`` or has no channel).
    """
    if u is None or u.shape[-1] == 0:
        return None
    U = torch.as_tensor(u, dtype=torch.float32)
    n = U.shape[1]

    def at(t: float) -> Tensor:
        x = min(max(t / dt, 0.0), n - 1.0)
        i = min(int(x), n - 2) if n > 1 else 0
        w = x - i
        return U[:, i] if n == 1 else (1 - w) * U[:, i] + w * U[:, i + 1]

    return at
