"""Compiled (numba) inference path for rollouts of a :class:`~lagsplat.models.lagrangian.Lagrangian`.

A rollout through torch costs ~2-3 ms per step at batch 1, almost all of it
autograd and dispatch overhead (two ``acceleration`` calls per step, each
taking ``dV/dq`` by autograd). This module exports the model's weights to
float64 NumPy arrays once (:func:`export_model`) and integrates the same
equation of motion (paper Eq. 7),

    ``M qddot = -dV/dq(q) - C(q) qdot + f_ext``,

with the same velocity-Verlet scheme as :func:`lagsplat.dynamics.integrators.verlet_step`
(paper Eq. 8; the second force evaluation uses the half-step velocity), in a
compiled loop with analytic gradients:

* ``dV/dq``: ``V = e^{s_V} (g(y) - g(y*) - grad g(y*)^T (y - y*) + eps/2 |y - y*|^2)``,
  ``y = phi(q)`` (``phi = id`` for the convex potential), so
  ``dV/dq = e^{s_V} Dphi(q)^T (grad g(y) - grad g(y*) + eps (y - y*))``;
  ``grad g`` by a hand-written backward pass through the ICNN (softplus with
  torch's threshold 20) and ``Dphi^T`` as a vector-Jacobian product through
  the i-ResNet blocks (ELU), whose weights are exported already rescaled to
  their spectral caps exactly as :meth:`IResNet.forward` does.
* ``C(q) qdot = e^{s_M} L(q) (L(q)^T qdot) + c0 qdot`` with ``L(q)`` the
  :class:`CholeskyField` MLP (ELU, softplus diagonal, ``tril_indices`` layout).
* ``M``: the constant inertia (``"scalar"``: ``e^{s_M} I``; ``"constant"``:
  the learned SPD matrix), inverted once.

``dV/dq`` and ``L`` depend on ``q`` only, so each step evaluates them once
(the first force evaluation of a step is at the position of the second one of
the previous step); the result is the same as evaluating them twice.

Supported: ``mass`` in ``{"scalar", "constant"}``, no actuation (``n_u = 0``),
convex or invex potential, any ICNN / MLP depth, constant (or no) external
force. :func:`lagsplat.dynamics.integrators.rollout` dispatches here
automatically for such models in eval mode (:func:`supports_fast`); the
export is cached per model and re-done when any parameter value changes
(:func:`cached_export`).

Units: time in seconds, state in the model's (whitened latent) units. All
arrays are float64, whatever the model's dtype.
"""

from __future__ import annotations

import dataclasses
import functools
import weakref

import numpy as np
import torch
from torch import Tensor, nn

from lagsplat.dynamics.fast_kernels import (
    accel_kernel,
    icnn_grad,
    phi_forward,
    rollout_kernel,
)
from lagsplat.models.icnn import ICNN, ConvexPotential, IResNet, spectral_norm_estimate
from lagsplat.models.inertia import CholeskyField
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

# ----------------------------------------------------------------------------- exported weights
@dataclasses.dataclass(frozen=True)
class FastModel:
    """Float64 weights of a supported :class:`Lagrangian`, ready for the compiled kernels.

    Layers of different widths are zero-padded into 3-D arrays; the true
    widths are kept alongside (``H`` = the largest width).

    Attributes:
        d: latent dimension.
        mass_kind: ``"scalar"`` or ``"constant"``.
        M, M_inv: ``[d,d]`` constant inertia and its inverse.
        exp_sV, exp_sM, c0, eps: ``e^{s_V}``, ``e^{s_M}``, the dissipation floor, the potential's quadratic floor.
        icnn_W ``[L,H,d]``, icnn_b ``[L,H]``: input weights / biases of the ICNN's ``L`` layers.
        icnn_R ``[L,H,H]``: ``softplus(R_l)`` feeding layer ``l`` from layer ``l-1`` (``icnn_R[0]`` unused, zero).
        icnn_out ``[H]``: ``softplus(w)`` of the output layer.
        icnn_widths ``[L]`` int64.
        q_rest ``[d]``: rest state ``q*``; y_rest ``[d]``: ``phi(q*)``; grad_rest ``[d]``: ``grad g(phi(q*))``.
        phi_W1 ``[nb,width,d]``, phi_b1 ``[nb,width]``, phi_W2 ``[nb,d,width]``, phi_b2 ``[nb,d]``:
            i-ResNet blocks with the spectral rescaling applied (``nb = 0``: convex potential).
        diss_W ``[n_layers,H,H]``, diss_b ``[n_layers,H]``, diss_in, diss_out ``[n_layers]`` int64:
            the dissipation MLP ``d -> hidden -> d(d+1)/2`` (ELU between layers).
        tril_i, tril_j ``[d(d+1)/2]`` int64: ``torch.tril_indices(d, d)``.
    """

    d: int
    mass_kind: str
    M: np.ndarray
    M_inv: np.ndarray
    exp_sV: float
    exp_sM: float
    c0: float
    eps: float
    icnn_W: np.ndarray
    icnn_b: np.ndarray
    icnn_R: np.ndarray
    icnn_out: np.ndarray
    icnn_widths: np.ndarray
    q_rest: np.ndarray
    y_rest: np.ndarray
    grad_rest: np.ndarray
    phi_W1: np.ndarray
    phi_b1: np.ndarray
    phi_W2: np.ndarray
    phi_b2: np.ndarray
    diss_W: np.ndarray
    diss_b: np.ndarray
    diss_in: np.ndarray
    diss_out: np.ndarray
    tril_i: np.ndarray
    tril_j: np.ndarray

    @functools.cached_property
    def _args(self) -> tuple:
        """Positional arguments of the kernels after the state (order matters).

        Weight matrices are passed transposed where the kernels accumulate
        ``out[:] += W[:, j] x[j]`` (contiguous, vectorisable inner loops without
        reassociating any sum): ``icnn_W``, ``softplus(R)`` (forward), ``phi_W1``
        and the dissipation layers; ``icnn_R`` and ``phi_W2`` as they are.
        """
        T = _transposed
        return (
            self.M_inv,
            self.exp_sV,
            self.exp_sM,
            self.c0,
            self.eps,
            T(self.icnn_W),
            self.icnn_b,
            self.icnn_R,
            T(self.icnn_R),
            self.icnn_out,
            self.icnn_widths,
            self.y_rest,
            self.grad_rest,
            T(self.phi_W1),
            self.phi_b1,
            self.phi_W2,
            self.phi_b2,
            T(self.diss_W),
            self.diss_b,
            self.diss_in,
            self.diss_out,
            self.tril_i,
            self.tril_j,
        )


# ----------------------------------------------------------------------------- support
_OVERRIDABLE = ("acceleration", "potential", "potential_grad", "mass_matrix", "dissipation_matrix", "generalized_force")


def unsupported_reason(model: object) -> str | None:
    """Why ``model`` cannot use the compiled path (``None`` when it can)."""
    if not isinstance(model, Lagrangian):
        return f"not a Lagrangian ({type(model).__name__})"
    for name in _OVERRIDABLE:  # a subclass changing the physics is not what the kernels implement
        if getattr(type(model), name) is not getattr(Lagrangian, name):
            return f"{type(model).__name__} overrides Lagrangian.{name}"
    if model.mass_kind not in ("scalar", "constant"):
        return f"mass={model.mass_kind!r} (only 'scalar' and 'constant' are compiled)"
    if model.n_u != 0 or model.actuation is not None:
        return f"actuation channels (n_u = {model.n_u})"
    pot = model.potential_hat
    if type(pot) is not ConvexPotential or type(pot.g) is not ICNN:
        return "potential is not the standard ConvexPotential(ICNN)"
    if pot.phi is not None and type(pot.phi) is not IResNet:
        return "invex map is not the standard IResNet"
    if type(model.dissipation) is not CholeskyField:
        return "dissipation is not the standard CholeskyField"
    mods = list(model.dissipation.net)
    lin, act = mods[0::2], mods[1::2]
    if (
        len(mods) % 2 != 1
        or not all(type(m) is nn.Linear for m in lin)
        or not all(type(m) is nn.ELU and float(m.alpha) == 1.0 for m in act)
    ):
        return "dissipation MLP is not Linear/ELU(alpha=1) layers"
    if any(p.device.type != "cpu" for p in model.parameters()):
        return "parameters are not on the CPU"
    return None


def supports_fast(model: object) -> bool:
    """Whether :func:`export_model` accepts ``model`` (the eval-mode check is the caller's)."""
    return unsupported_reason(model) is None


def _transposed(a: np.ndarray) -> np.ndarray:
    """``a`` with its last two axes swapped, contiguous."""
    return np.ascontiguousarray(np.swapaxes(a, 1, 2))


def _np(t: Tensor) -> np.ndarray:
    return t.detach().to(torch.float64).cpu().numpy()


@torch.no_grad()
def export_model(model: Lagrangian) -> FastModel:
    """Export a supported :class:`Lagrangian` to a :class:`FastModel` (float64 arrays).

    Raises:
        ValueError: if the model is not supported (see :func:`unsupported_reason`).
    """
    why = unsupported_reason(model)
    if why is not None:
        raise ValueError(f"the compiled rollout does not support this model: {why}")
    d = model.d
    pot = model.potential_hat
    g = pot.g
    # ICNN (softplus applied to the non-negative weights)
    widths = np.array([lin.out_features for lin in g.inp], np.int64)
    L, H = len(widths), int(widths.max())
    icnn_W = np.zeros((L, H, d))
    icnn_b = np.zeros((L, H))
    icnn_R = np.zeros((L, H, H))
    for l, lin in enumerate(g.inp):
        icnn_W[l, : widths[l]] = _np(lin.weight)
        icnn_b[l, : widths[l]] = _np(lin.bias)
    for l, R in enumerate(g.rec, start=1):
        icnn_R[l, : widths[l], : widths[l - 1]] = _np(torch.nn.functional.softplus(R))
    icnn_out = np.zeros(H)
    icnn_out[: widths[-1]] = _np(torch.nn.functional.softplus(g.out))
    # i-ResNet, rescaled exactly as IResNet.forward (in the model's dtype), then float64
    if pot.phi is not None:
        phi = pot.phi
        nb = len(phi.l1)
        width = phi.l1[0].out_features if nb else 1
        W1, b1 = np.zeros((nb, width, d)), np.zeros((nb, width))
        W2, b2 = np.zeros((nb, d, width)), np.zeros((nb, d))
        for k, (a, b) in enumerate(zip(phi.l1, phi.l2)):
            W1[k] = _np(a.weight / spectral_norm_estimate(a.weight).clamp_min(1.0))
            W2[k] = _np(b.weight * (phi.lip / spectral_norm_estimate(b.weight).clamp_min(phi.lip)))
            b1[k], b2[k] = _np(a.bias), _np(b.bias)
    else:
        W1, b1, W2, b2 = np.zeros((0, 1, d)), np.zeros((0, 1)), np.zeros((0, d, 1)), np.zeros((0, d))
    # dissipation MLP
    lins = list(model.dissipation.net)[0::2]
    Hd = max(max(m.in_features, m.out_features) for m in lins)
    diss_W = np.zeros((len(lins), Hd, Hd))
    diss_b = np.zeros((len(lins), Hd))
    diss_in = np.array([m.in_features for m in lins], np.int64)
    diss_out = np.array([m.out_features for m in lins], np.int64)
    for k, m in enumerate(lins):
        diss_W[k, : m.out_features, : m.in_features] = _np(m.weight)
        diss_b[k, : m.out_features] = _np(m.bias)
    # constant inertia
    M = _np(model.mass_matrix(model.q_rest.detach()[None])[0])
    q_rest = _np(model.q_rest)
    y_rest = q_rest.copy()
    T = _transposed  # kernel layouts, see FastModel._args
    if W1.shape[0]:
        nb, width = b1.shape
        y_rest = phi_forward(q_rest, T(W1), b1, W2, b2, np.zeros((nb, d)), np.zeros((nb, width)), np.zeros(width))
    grad_rest = np.zeros(d)
    icnn_grad(y_rest, T(icnn_W), icnn_b, icnn_R, T(icnn_R), icnn_out, widths, np.zeros((L, H)), np.zeros((L, H)), np.zeros(H), np.zeros(H), grad_rest)
    return FastModel(
        d=d,
        mass_kind=model.mass_kind,
        M=M,
        M_inv=np.linalg.inv(M),
        exp_sV=float(torch.exp(model.s_V.detach().double())),
        exp_sM=float(torch.exp(model.s_M.detach().double())),
        c0=float(model.c0),
        eps=float(pot.eps),
        icnn_W=icnn_W,
        icnn_b=icnn_b,
        icnn_R=icnn_R,
        icnn_out=icnn_out,
        icnn_widths=widths,
        q_rest=q_rest,
        y_rest=y_rest,
        grad_rest=grad_rest,
        phi_W1=W1,
        phi_b1=b1,
        phi_W2=W2,
        phi_b2=b2,
        diss_W=diss_W,
        diss_b=diss_b,
        diss_in=diss_in,
        diss_out=diss_out,
        tril_i=_np(model.dissipation.ii).astype(np.int64),
        tril_j=_np(model.dissipation.jj).astype(np.int64),
    )


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


def fast_rollout(
    fm: FastModel,
    q0: np.ndarray,
    qdot0: np.ndarray,
    h: float,
    n_states: int,
    f_ext: np.ndarray | None = None,
    u: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Compiled velocity-Verlet rollout, same scheme as :func:`lagsplat.dynamics.integrators.rollout`.

    Args:
        fm: the exported model (:func:`export_model` / :func:`cached_export`).
        q0, qdot0: ``[B,d]`` initial state (arrays or tensors; computed in float64).
        h: step in seconds.
        n_states: number of states returned, the initial one included.
        f_ext: constant generalized force broadcastable to ``[B,d]``, or ``None``.
        u: must be ``None`` (actuation is not compiled).

    Returns:
        ``(q [B,n_states,d], qdot [B,n_states,d])`` float64. A trajectory that
        becomes non-finite keeps NaN from that step on.

    Raises:
        ValueError: on an actuation ``u`` or mismatched shapes.
    """
    if u is not None:
        raise ValueError("the compiled rollout has no actuation channels; pass u=None (or use the torch path)")
    q0a, v0a = _as_state(q0, "q0"), _as_state(qdot0, "qdot0")
    if q0a.shape != v0a.shape or q0a.shape[1] != fm.d:
        raise ValueError(f"q0 {q0a.shape} and qdot0 {v0a.shape} must both be [B,{fm.d}]")
    B = q0a.shape[0]
    f = _as_force(f_ext, B, fm.d)
    return rollout_kernel(q0a, v0a, f, float(h), max(int(n_states), 1), *fm._args)


def fast_acceleration(fm: FastModel, q: np.ndarray, qdot: np.ndarray, f_ext: np.ndarray | None = None) -> np.ndarray:
    """``qddot [B,d]`` of the exported model (the compiled counterpart of ``Lagrangian.acceleration``)."""
    qa, va = _as_state(q, "q"), _as_state(qdot, "qdot")
    return accel_kernel(qa, va, _as_force(f_ext, qa.shape[0], fm.d), *fm._args)[0]


def fast_potential_grad(fm: FastModel, q: np.ndarray) -> np.ndarray:
    """``dV/dq [B,d]`` of the exported model (hand-written backprop)."""
    qa = _as_state(q, "q")
    return accel_kernel(qa, np.zeros_like(qa), np.zeros_like(qa), *fm._args)[1]
