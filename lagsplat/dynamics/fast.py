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
import math
import weakref

import numpy as np
import torch
from numba import njit
from torch import Tensor, nn

from lagsplat.models.icnn import ICNN, ConvexPotential, IResNet, spectral_norm_estimate
from lagsplat.models.lagrangian import CholeskyField, Lagrangian

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
        y_rest = _phi_forward(q_rest, T(W1), b1, W2, b2, np.zeros((nb, d)), np.zeros((nb, width)), np.zeros(width))
    grad_rest = np.zeros(d)
    _icnn_grad(y_rest, T(icnn_W), icnn_b, icnn_R, T(icnn_R), icnn_out, widths, np.zeros((L, H)), np.zeros((L, H)), np.zeros(H), np.zeros(H), grad_rest)
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


# ----------------------------------------------------------------------------- compiled kernels
@njit(cache=True)
def _softplus(x):  # pragma: no cover - compiled
    return x if x > 20.0 else math.log1p(math.exp(x))


@njit(cache=True)
def _elu(x):  # pragma: no cover - compiled
    return x if x > 0.0 else math.expm1(x)


@njit(cache=True)
def _elu_prime(x):  # pragma: no cover - compiled
    return 1.0 if x > 0.0 else math.exp(x)


@njit(cache=True)
def _vecmat(x, A, n, m, out):  # pragma: no cover - compiled
    """``out[:m] = x[:n] @ A[:n, :m]`` for a 2-D ``A`` (row by row, contiguous inner loop)."""
    for j in range(m):
        out[j] = 0.0
    for i in range(n):
        xi = x[i]
        for j in range(m):
            out[j] += A[i, j] * xi


@njit(cache=True)
def _icnn_grad(x, WT, b, R, RT, w_out, widths, z, hbuf, dh, dh2, gx):  # pragma: no cover - compiled
    """``gx[:] = grad g(x)`` for the ICNN ``g`` (forward, then hand-written backprop).

    ``WT [L,d,H]``: input weights transposed; ``R``/``RT [L,H,H]``: ``softplus(R_l)`` and its
    transpose. ``z, hbuf [L,H]``: softplus derivatives / activations (workspace); ``dh, dh2 [H]``:
    workspace. Softplus and its derivative share one ``exp`` (torch's formulas:
    ``log1p(e^s)``, ``e^s / (e^s + 1)``, identity above the threshold 20).
    """
    L = widths.shape[0]
    d = x.shape[0]
    for l in range(L):
        n = widths[l]
        for i in range(n):
            dh[i] = b[l, i]
        for k in range(d):
            xk = x[k]
            for i in range(n):
                dh[i] += WT[l, k, i] * xk
        if l > 0:
            for j in range(widths[l - 1]):
                hj = hbuf[l - 1, j]
                for i in range(n):
                    dh[i] += RT[l, j, i] * hj
        for i in range(n):
            s = dh[i]
            if s > 20.0:
                hbuf[l, i] = s
                z[l, i] = 1.0
            else:
                e = math.exp(s)
                hbuf[l, i] = math.log1p(e)
                z[l, i] = e / (e + 1.0)
    for k in range(d):
        gx[k] = 0.0
    n = widths[L - 1]
    for i in range(n):
        dh[i] = w_out[i]
    for l in range(L - 1, -1, -1):
        n = widths[l]
        for i in range(n):
            dh[i] *= z[l, i]  # now dg/d(pre-activation of layer l)
        for k in range(d):
            s = 0.0
            for i in range(n):
                s += WT[l, k, i] * dh[i]
            gx[k] += s
        if l > 0:
            m = widths[l - 1]
            _vecmat(dh, R[l], n, m, dh2)
            for j in range(m):
                dh[j] = dh2[j]


@njit(cache=True)
def _phi_forward(x, W1T, b1, W2, b2, X, Z, t):  # pragma: no cover - compiled
    """``phi(x)`` through the i-ResNet blocks ``x + W2 elu(W1 x + b1) + b2``.

    ``W1T [nb,d,width]`` (transposed), ``W2 [nb,d,width]``. Stores each block's input
    ``X [nb,d]`` and pre-activation ``Z [nb,width]``; ``t [width]`` workspace.
    """
    nb = W1T.shape[0]
    width = W1T.shape[2]
    d = x.shape[0]
    y = x.copy()
    for k in range(nb):
        for c in range(d):
            X[k, c] = y[c]
        for i in range(width):
            Z[k, i] = b1[k, i]
        for c in range(d):
            xc = X[k, c]
            for i in range(width):
                Z[k, i] += W1T[k, c, i] * xc
        for i in range(width):
            t[i] = _elu(Z[k, i])
        for c in range(d):
            s = b2[k, c]
            for i in range(width):
                s += W2[k, c, i] * t[i]
            y[c] = X[k, c] + s
    return y


@njit(cache=True)
def _phi_vjp(g, W1T, W2, Z, t):  # pragma: no cover - compiled
    """In place ``g <- Dphi(x)^T g`` from the stored pre-activations ``Z`` (``t [width]`` workspace)."""
    nb = W1T.shape[0]
    width = W1T.shape[2]
    d = g.shape[0]
    for k in range(nb - 1, -1, -1):
        # block y = x + W2 elu(W1 x + b1) + b2:  g_x = g_y + W1^T (elu'(z) * (W2^T g_y))
        _vecmat(g, W2[k], d, width, t)
        for i in range(width):
            t[i] *= _elu_prime(Z[k, i])
        for c in range(d):
            s = 0.0
            for i in range(width):
                s += W1T[k, c, i] * t[i]
            g[c] += s


@njit(cache=True)
def _grad_V(q, exp_sV, eps, icnn_WT, icnn_b, icnn_R, icnn_RT, icnn_out, icnn_widths, y_rest, grad_rest, phi_W1T, phi_b1, phi_W2, phi_b2, ws_z, ws_h, ws_dh, ws_dh2, ws_X, ws_Z, ws_t, gq):  # pragma: no cover
    """``gq[:] = dV/dq(q)`` (paper §3.3; App. A.2 (A2)): ``e^{s_V} Dphi^T (grad g(y) - grad g(y*) + eps (y - y*))``."""
    d = q.shape[0]
    if phi_W1T.shape[0] > 0:
        y = _phi_forward(q, phi_W1T, phi_b1, phi_W2, phi_b2, ws_X, ws_Z, ws_t)
    else:
        y = q.copy()
    _icnn_grad(y, icnn_WT, icnn_b, icnn_R, icnn_RT, icnn_out, icnn_widths, ws_z, ws_h, ws_dh, ws_dh2, gq)
    for c in range(d):
        gq[c] = gq[c] - grad_rest[c] + eps * (y[c] - y_rest[c])
    if phi_W1T.shape[0] > 0:
        _phi_vjp(gq, phi_W1T, phi_W2, ws_Z, ws_t)
    for c in range(d):
        gq[c] *= exp_sV


@njit(cache=True)
def _chol_factor(q, diss_WT, diss_b, diss_in, diss_out, tril_i, tril_j, a, a2, Lm):  # pragma: no cover
    """``Lm [d,d] = L_C(q)``, the dissipation's Cholesky factor (MLP with ELU, softplus diagonal).

    ``diss_WT [n_layers,H_in,H_out]``: the layers' weights, transposed.
    """
    d = q.shape[0]
    n_layers = diss_in.shape[0]
    for c in range(d):
        a[c] = q[c]
    for k in range(n_layers):
        no = diss_out[k]
        for i in range(no):
            a2[i] = diss_b[k, i]
        for j in range(diss_in[k]):
            aj = a[j]
            for i in range(no):
                a2[i] += diss_WT[k, j, i] * aj
        if k < n_layers - 1:
            for i in range(no):
                a[i] = _elu(a2[i])
        else:
            for i in range(no):
                a[i] = a2[i]
    for r in range(d):
        for c in range(d):
            Lm[r, c] = 0.0
    for t in range(tril_i.shape[0]):
        r = tril_i[t]
        c = tril_j[t]
        Lm[r, c] = _softplus(a[t]) if r == c else a[t]


@njit(cache=True)
def _accel(gV, Lm, v, f, M_inv, exp_sM, c0, tmp, force, out):  # pragma: no cover
    """``out = M^-1 (-gV - C v + f)``, ``C v = e^{s_M} L (L^T v) + c0 v`` (paper Eq. 7, constant M)."""
    d = v.shape[0]
    for c in range(d):  # tmp = L^T v
        s = 0.0
        for r in range(d):
            s += Lm[r, c] * v[r]
        tmp[c] = s
    for r in range(d):
        s = 0.0
        for c in range(d):
            s += Lm[r, c] * tmp[c]
        force[r] = -gV[r] - (exp_sM * s + c0 * v[r]) + f[r]
    for r in range(d):
        s = 0.0
        for c in range(d):
            s += M_inv[r, c] * force[c]
        out[r] = s


@njit(cache=True)
def _workspace(d, icnn_b, phi_b1, diss_b):  # pragma: no cover
    """Scratch arrays of :func:`_position_terms` for states of dimension ``d``, sized by the padded layer widths.

    Returns the tuple ``(ws_z, ws_h, ws_dh, ws_dh2, ws_X, ws_Z, ws_t, a, a2)``:
    ICNN activations ``[L,H]`` x 2 and gradients ``[H]`` x 2, i-ResNet block
    inputs ``[nb,d]``, pre-activations ``[nb,width]`` and a ``[width]``
    buffer, and two dissipation-MLP activations ``[max(Hd, d)]``.
    """
    L, H = icnn_b.shape[0], icnn_b.shape[1]
    nb, width = phi_b1.shape[0], phi_b1.shape[1]
    Hd = max(diss_b.shape[1], d)
    return np.zeros((L, H)), np.zeros((L, H)), np.zeros(H), np.zeros(H), np.zeros((nb, d)), np.zeros((nb, width)), np.zeros(width), np.zeros(Hd), np.zeros(Hd)


@njit(cache=True, inline="always")  # inlined into the step loop (no tuple passing per call)
def _position_terms(q, exp_sV, eps, icnn_WT, icnn_b, icnn_R, icnn_RT, icnn_out, icnn_widths, y_rest, grad_rest, phi_W1T, phi_b1, phi_W2, phi_b2, diss_WT, diss_b, diss_in, diss_out, tril_i, tril_j, ws, gV, Lm):  # pragma: no cover
    """The position-only terms at ``q [d]``: ``gV = dV/dq(q)`` and ``Lm = L(q)`` (in place; ``ws`` from :func:`_workspace`)."""
    ws_z, ws_h, ws_dh, ws_dh2, ws_X, ws_Z, ws_t, a, a2 = ws
    _grad_V(q, exp_sV, eps, icnn_WT, icnn_b, icnn_R, icnn_RT, icnn_out, icnn_widths, y_rest, grad_rest, phi_W1T, phi_b1, phi_W2, phi_b2, ws_z, ws_h, ws_dh, ws_dh2, ws_X, ws_Z, ws_t, gV)
    _chol_factor(q, diss_WT, diss_b, diss_in, diss_out, tril_i, tril_j, a, a2, Lm)


@njit(cache=True)
def _rollout_kernel(q0, v0, f, h, n, M_inv, exp_sV, exp_sM, c0, eps, icnn_WT, icnn_b, icnn_R, icnn_RT, icnn_out, icnn_widths, y_rest, grad_rest, phi_W1T, phi_b1, phi_W2, phi_b2, diss_WT, diss_b, diss_in, diss_out, tril_i, tril_j):  # pragma: no cover
    """Velocity-Verlet rollouts (paper Eq. 8) of ``B`` trajectories; returns ``(q, v) [B,n,d]``.

    Per step: ``a1 = a(q, v)``; ``vh = v + h/2 a1``; ``q1 = q + h vh``;
    ``a2 = a(q1, vh)``; ``v1 = vh + h/2 a2``. A trajectory whose state turns
    non-finite is NaN from that step on.
    """
    B, d = q0.shape
    qs = np.empty((B, n, d))
    vs = np.empty((B, n, d))
    ws = _workspace(d, icnn_b, phi_b1, diss_b)
    Lm = np.zeros((d, d))
    gV, tmp, force, acc = np.zeros(d), np.zeros(d), np.zeros(d), np.zeros(d)
    q, v, vh = np.zeros(d), np.zeros(d), np.zeros(d)
    for b in range(B):
        for c in range(d):
            q[c] = q0[b, c]
            v[c] = v0[b, c]
            qs[b, 0, c] = q[c]
            vs[b, 0, c] = v[c]
        _position_terms(q, exp_sV, eps, icnn_WT, icnn_b, icnn_R, icnn_RT, icnn_out, icnn_widths, y_rest, grad_rest, phi_W1T, phi_b1, phi_W2, phi_b2, diss_WT, diss_b, diss_in, diss_out, tril_i, tril_j, ws, gV, Lm)
        for i in range(1, n):
            _accel(gV, Lm, v, f[b], M_inv, exp_sM, c0, tmp, force, acc)
            for c in range(d):
                vh[c] = v[c] + 0.5 * h * acc[c]
                q[c] = q[c] + h * vh[c]
            _position_terms(q, exp_sV, eps, icnn_WT, icnn_b, icnn_R, icnn_RT, icnn_out, icnn_widths, y_rest, grad_rest, phi_W1T, phi_b1, phi_W2, phi_b2, diss_WT, diss_b, diss_in, diss_out, tril_i, tril_j, ws, gV, Lm)
            _accel(gV, Lm, vh, f[b], M_inv, exp_sM, c0, tmp, force, acc)
            finite = True
            for c in range(d):
                v[c] = vh[c] + 0.5 * h * acc[c]
                if not (math.isfinite(q[c]) and math.isfinite(v[c])):
                    finite = False
            if not finite:
                for j in range(i, n):
                    for c in range(d):
                        qs[b, j, c] = np.nan
                        vs[b, j, c] = np.nan
                break
            for c in range(d):
                qs[b, i, c] = q[c]
                vs[b, i, c] = v[c]
    return qs, vs


@njit(cache=True)
def _accel_kernel(q, v, f, M_inv, exp_sV, exp_sM, c0, eps, icnn_WT, icnn_b, icnn_R, icnn_RT, icnn_out, icnn_widths, y_rest, grad_rest, phi_W1T, phi_b1, phi_W2, phi_b2, diss_WT, diss_b, diss_in, diss_out, tril_i, tril_j):  # pragma: no cover
    """``(qddot, dV/dq)`` at ``B`` states, each ``[B,d]``."""
    B, d = q.shape
    out = np.empty((B, d))
    gout = np.empty((B, d))
    ws = _workspace(d, icnn_b, phi_b1, diss_b)
    Lm = np.zeros((d, d))
    gV, tmp, force, acc = np.zeros(d), np.zeros(d), np.zeros(d), np.zeros(d)
    for b in range(B):
        qb = q[b].copy()
        _position_terms(qb, exp_sV, eps, icnn_WT, icnn_b, icnn_R, icnn_RT, icnn_out, icnn_widths, y_rest, grad_rest, phi_W1T, phi_b1, phi_W2, phi_b2, diss_WT, diss_b, diss_in, diss_out, tril_i, tril_j, ws, gV, Lm)
        _accel(gV, Lm, v[b], f[b], M_inv, exp_sM, c0, tmp, force, acc)
        for c in range(d):
            out[b, c] = acc[c]
            gout[b, c] = gV[c]
    return out, gout


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
    return _rollout_kernel(q0a, v0a, f, float(h), max(int(n_states), 1), *fm._args)


def fast_acceleration(fm: FastModel, q: np.ndarray, qdot: np.ndarray, f_ext: np.ndarray | None = None) -> np.ndarray:
    """``qddot [B,d]`` of the exported model (the compiled counterpart of ``Lagrangian.acceleration``)."""
    qa, va = _as_state(q, "q"), _as_state(qdot, "qdot")
    return _accel_kernel(qa, va, _as_force(f_ext, qa.shape[0], fm.d), *fm._args)[0]


def fast_potential_grad(fm: FastModel, q: np.ndarray) -> np.ndarray:
    """``dV/dq [B,d]`` of the exported model (hand-written backprop)."""
    qa = _as_state(q, "q")
    return _accel_kernel(qa, np.zeros_like(qa), np.zeros_like(qa), *fm._args)[1]
