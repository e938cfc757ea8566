"""Compiled (numba) inference path for rollouts of a :class:`~lagsplat.models.lagrangian.Lagrangian`.

A rollout through torch costs milliseconds per step at batch 1 (``benchmarks/rollout.py``,
``results/benchmarks/rollout.md``), almost all of it autograd and dispatch overhead (two ``acceleration``
calls per step, each taking ``dV/dq`` by autograd, and with a learned inertia ``d`` more backward passes
for the velocity terms). This module exports the model's weights to
float64 NumPy arrays once (:func:`~lagsplat.dynamics.fast_export.export_model`) and integrates the same
equation of motion (paper Eq. 7),

    ``M(q) qddot = dT/dq - (d(M qdot)/dq) qdot - dV/dq - C(q) qdot + f_ext + b(q)^T u``,

with the same velocity-Verlet scheme as :func:`lagsplat.dynamics.integrators.verlet_step` (paper Eq. 8;
the second force evaluation uses the half-step velocity), in a compiled loop with analytic gradients
(:mod:`lagsplat.dynamics.fast_loop`): ``dV/dq`` by a hand-written backward pass through the ICNN and a
vector-Jacobian product through the i-ResNet; ``C(q)`` and a learned ``M(q)`` from their Cholesky MLPs, the
derivatives of ``M`` by forward mode; the actuation Jacobian ``b(q)`` of the concave map (paper Eq. 6) by the
same ICNN backward pass. Every position-only term is evaluated once per step (the first force evaluation of a
step is at the position of the second one of the previous step).

Supported (:func:`~lagsplat.dynamics.fast_export.unsupported_reason`): ``mass`` in ``{"scalar", "constant",
"learned"}``, any number of actuation channels, convex or invex potential, any ICNN / MLP depth, a constant
(or no) external force. :func:`lagsplat.dynamics.integrators.rollout` dispatches here automatically for such
models in eval mode; the export is cached per model and re-done when any parameter value changes
(:func:`cached_export`).

Units: time in seconds, state in the model's (whitened latent) units. All arrays are float64, whatever the
model's dtype.
"""

from __future__ import annotations

import weakref

import numpy as np
import torch
from torch import Tensor, nn

from lagsplat.dynamics.fast_export import FastModel, export_model, supports_fast, unsupported_reason
from lagsplat.dynamics.fast_loop import accel_kernel, rollout_kernel
from lagsplat.models.lagrangian import Lagrangian

__all__ = [
    "FastModel",
    "cached_export",
    "export_model",
    "fast_acceleration",
    "fast_potential_grad",
    "fast_rollout",
    "supports_fast",
    "unsupported_reason",
]

# Export cache. Keyed weakly by the model; an entry is valid while the model's
# structure/scalar settings are unchanged AND every parameter/buffer still
# holds the exported values. Values are compared (torch.equal on a snapshot),
# not autograd version counters: a fused optimizer step (e.g. AdamW(fused=True))
# and writes through ``p.data`` leave ``p._version`` unchanged, so a
# version/data_ptr fingerprint alone would serve stale weights. The comparison
# costs a few microseconds per tensor, negligible against a rollout.
_CACHE: weakref.WeakKeyDictionary[nn.Module, tuple[tuple, list[Tensor], FastModel]] = weakref.WeakKeyDictionary()


def _structure_key(model: Lagrangian) -> tuple:
    pot = model.potential_hat
    tensors = [(n, t.dtype, tuple(t.shape)) for n, t in list(model.named_parameters()) + list(model.named_buffers())]
    return (tuple(tensors), model.mass_kind, float(model.c0), float(pot.eps), None if pot.phi is None else float(pot.phi.lip))


def cached_export(model: Lagrangian) -> FastModel:
    """:func:`export_model`, cached on ``model`` until a parameter value or setting changes.

    Raises:
        ValueError: if the model is not supported.
    """
    key = _structure_key(model)
    tensors = [t for _, t in list(model.named_parameters()) + list(model.named_buffers())]
    hit = _CACHE.get(model)
    if hit is not None and hit[0] == key and all(torch.equal(a, b) for a, b in zip(tensors, hit[1])):
        return hit[2]
    fm = export_model(model)
    _CACHE[model] = (key, [t.detach().clone() for t in tensors], fm)
    return fm


# ----------------------------------------------------------------------------- public entry points
def _as_state(x, name: str) -> np.ndarray:
    a = x.detach().cpu().numpy() if isinstance(x, Tensor) else np.asarray(x)
    a = np.ascontiguousarray(a, dtype=np.float64)
    if a.ndim != 2:
        raise ValueError(f"{name} must be [B,d], got shape {a.shape}")
    return a


def _as_force(f_ext, B: int, d: int) -> np.ndarray:
    if f_ext is None:
        return np.zeros((B, d))
    f = f_ext.detach().cpu().numpy() if isinstance(f_ext, Tensor) else np.asarray(f_ext)
    return np.ascontiguousarray(np.broadcast_to(np.asarray(f, np.float64), (B, d)))


def _as_actuation(u, B: int, n_steps: int, n_u: int, name: str) -> np.ndarray:
    """``u`` as ``[B, n_steps, n_u]`` float64: ``None`` (zero), a constant ``[B or 1, n_u]`` or per step ``[B or 1, n_steps, n_u]``."""
    if u is None:  # no actuation: zero pressures, as on the torch path
        return np.zeros((B, n_steps, n_u))
    a = u.detach().cpu().numpy() if isinstance(u, Tensor) else np.asarray(u)
    a = np.asarray(a, np.float64)
    if a.shape[-1] != n_u or a.ndim not in (2, 3):
        raise ValueError(f"{name} must be [B,{n_u}] or [B,n_steps,{n_u}] for a model with {n_u} actuation channels, got shape {a.shape}")
    if a.ndim == 2:
        a = a[:, None, :]
    return np.ascontiguousarray(np.broadcast_to(a, (B, n_steps, n_u)))


def fast_rollout(
    fm: FastModel,
    q0: np.ndarray,
    qdot0: np.ndarray,
    h: float,
    n_states: int,
    f_ext: np.ndarray | None = None,
    u: np.ndarray | None = None,
    u_end: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Compiled velocity-Verlet rollout, same scheme as :func:`lagsplat.dynamics.integrators.rollout`.

    Args:
        fm: the exported model (:func:`export_model` / :func:`cached_export`).
        q0, qdot0: ``[B,d]`` initial state (arrays or tensors; computed in float64).
        h: step in seconds.
        n_states: number of states returned, the initial one included.
        f_ext: constant generalized force broadcastable to ``[B,d]``, or ``None``.
        u: actuation of a model with ``n_u`` channels (pressures, paper Eq. 6): a constant ``[B,n_u]``, or
            per step ``[B,n_states-1,n_u]``, used at the step's first force evaluation (and its second, unless
            ``u_end`` is given: a zero-order hold); ``None``: no actuation (zero pressures).
        u_end: the actuation at each step's second force evaluation (time ``t + h``), same shapes, or ``None``.

    Returns:
        ``(q [B,n_states,d], qdot [B,n_states,d])`` float64. A trajectory that
        becomes non-finite (or whose learned inertia stops being positive definite) keeps NaN from that step on.

    Raises:
        ValueError: on mismatched shapes, or an actuation given to a model without channels.
    """
    q0a, v0a = _as_state(q0, "q0"), _as_state(qdot0, "qdot0")
    if q0a.shape != v0a.shape or q0a.shape[1] != fm.d:
        raise ValueError(f"q0 {q0a.shape} and qdot0 {v0a.shape} must both be [B,{fm.d}]")
    B, n = q0a.shape[0], max(int(n_states), 1)
    if u is not None and fm.n_u == 0:
        raise ValueError("the model has no actuation channels; pass u=None")
    Ua = _as_actuation(u, B, n - 1, fm.n_u, "u")
    Ub = Ua if u_end is None else _as_actuation(u_end, B, n - 1, fm.n_u, "u_end")
    return rollout_kernel(q0a, v0a, _as_force(f_ext, B, fm.d), Ua, Ub, float(h), n, *fm.kernel_args)


def fast_acceleration(fm: FastModel, q: np.ndarray, qdot: np.ndarray, f_ext: np.ndarray | None = None, u: np.ndarray | None = None) -> np.ndarray:
    """``qddot [B,d]`` of the exported model under actuation ``u [B,n_u]`` (the compiled ``Lagrangian.acceleration``)."""
    qa, va = _as_state(q, "q"), _as_state(qdot, "qdot")
    Ua = _as_actuation(u, qa.shape[0], 1, fm.n_u, "u")[:, 0]
    return accel_kernel(qa, va, _as_force(f_ext, qa.shape[0], fm.d), np.ascontiguousarray(Ua), *fm.kernel_args)[0]


def fast_potential_grad(fm: FastModel, q: np.ndarray) -> np.ndarray:
    """``dV/dq [B,d]`` of the exported model (hand-written backprop)."""
    qa = _as_state(q, "q")
    z = np.zeros_like(qa)
    return accel_kernel(qa, z, z, np.zeros((qa.shape[0], fm.n_u)), *fm.kernel_args)[1]
