"""Export of a :class:`~lagsplat.models.lagrangian.Lagrangian` to the float64 arrays of the compiled rollout path.

:func:`export_model` reads the weights once into a :class:`FastModel`; :func:`unsupported_reason` says why a
model cannot take that path. What the kernels (:mod:`lagsplat.dynamics.fast_loop`) implement, paper Eq. 7:

* the potential: ``V = e^{s_V} (g(y) - g(y*) - grad g(y*)^T (y - y*) + eps/2 |y - y*|^2)``, ``y = phi(q)``
  (``phi = id`` for the convex potential, an i-ResNet for the invex one), ICNN ``g``;
* the dissipation ``C(q) = e^{s_M} L_C(q) L_C(q)^T + c0 I`` (:class:`CholeskyField` MLP, ELU);
* the inertia: ``"scalar"`` (``e^{s_M} I``), ``"constant"`` (the learned SPD matrix) or ``"learned"``
  (``M(q) = e^{s_M} (L_M(q) L_M(q)^T + 0.1 I) / 1.1``, with the velocity terms of the Euler-Lagrange equation);
* the actuation ``f_P = e^{s_V} sum_j u_j (a_j - grad g_j(q))`` of the concave map (paper Eq. 6), any ``n_u``.

Not compiled: the decoder-induced inertia (``mass="decoder"``) and subclasses that change the physics.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
import torch
from torch import Tensor, nn

from lagsplat.dynamics.fast_kernels import icnn_grad, phi_forward
from lagsplat.models.icnn import ICNN, ConcaveMap, ConvexPotential, IResNet, spectral_norm_estimate
from lagsplat.models.inertia import CholeskyField
from lagsplat.models.lagrangian import Lagrangian

__all__ = ["FastModel", "export_model", "supports_fast", "unsupported_reason"]

COMPILED_MASS = ("scalar", "constant", "learned")
"""Inertia forms the compiled path implements."""


@dataclasses.dataclass(frozen=True)
class FastModel:
    """Float64 weights of a supported :class:`Lagrangian`, ready for the compiled kernels.

    Layers of different widths are zero-padded into 3-D arrays; the true widths are kept alongside
    (``H`` = the largest width).

    Attributes:
        d: latent dimension; n_u: actuation channels.
        mass_kind: ``"scalar"``, ``"constant"`` or ``"learned"``.
        M, M_inv: ``[d,d]`` constant inertia and its inverse (at ``q*`` for ``"learned"``, unused by the kernels).
        exp_sV, exp_sM, c0, eps: ``e^{s_V}``, ``e^{s_M}``, the dissipation floor, the potential's quadratic floor.
        icnn_W ``[L,H,d]``, icnn_b ``[L,H]``: input weights / biases of the ICNN's ``L`` layers.
        icnn_R ``[L,H,H]``: ``softplus(R_l)`` feeding layer ``l`` from layer ``l-1`` (``icnn_R[0]`` unused, zero).
        icnn_out ``[H]``: ``softplus(w)`` of the output layer; icnn_widths ``[L]`` int64.
        q_rest ``[d]``: rest state ``q*``; y_rest ``[d]``: ``phi(q*)``; grad_rest ``[d]``: ``grad g(phi(q*))``.
        phi_W1 ``[nb,width,d]``, phi_b1 ``[nb,width]``, phi_W2 ``[nb,d,width]``, phi_b2 ``[nb,d]``:
            i-ResNet blocks with the spectral rescaling applied (``nb = 0``: convex potential).
        diss_W ``[n_layers,H,H]``, diss_b ``[n_layers,H]``, diss_in, diss_out ``[n_layers]`` int64:
            the dissipation MLP ``d -> hidden -> d(d+1)/2`` (ELU between layers).
        mass_W, mass_b, mass_in, mass_out: the learned inertia's MLP in the same layout (zero layers otherwise).
        act_a ``[n_u,d]``; act_W ``[n_u,La,Ha,d]``, act_b ``[n_u,La,Ha]``, act_R ``[n_u,La,Ha,Ha]``,
            act_out ``[n_u,Ha]``, act_widths ``[La]``: the concave map's linear part and ICNN heads.
        tril_i, tril_j ``[d(d+1)/2]`` int64: ``torch.tril_indices(d, d)``.
    """

    d: int
    n_u: int
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
    mass_W: np.ndarray
    mass_b: np.ndarray
    mass_in: np.ndarray
    mass_out: np.ndarray
    act_a: np.ndarray
    act_W: np.ndarray
    act_b: np.ndarray
    act_R: np.ndarray
    act_out: np.ndarray
    act_widths: np.ndarray
    tril_i: np.ndarray
    tril_j: np.ndarray

    @functools.cached_property
    def kernel_args(self) -> tuple:
        """Positional arguments of the kernels after the state, forces and step (order matters).

        Weight matrices are passed transposed where the kernels accumulate ``out[:] += W[:, j] x[j]``
        (contiguous, vectorisable inner loops without reassociating any sum).
        """
        T = _transposed
        return (self.M_inv, self.exp_sV, self.exp_sM, self.c0, self.eps, T(self.icnn_W), self.icnn_b, self.icnn_R, T(self.icnn_R),
                self.icnn_out, self.icnn_widths, self.y_rest, self.grad_rest, T(self.phi_W1), self.phi_b1, self.phi_W2, self.phi_b2,
                T(self.diss_W), self.diss_b, self.diss_in, self.diss_out, self.tril_i, self.tril_j, T(self.mass_W), self.mass_b,
                self.mass_in, self.mass_out, self.act_a, _transposed(self.act_W), self.act_b, self.act_R, _transposed(self.act_R),
                self.act_out, self.act_widths)  # fmt: skip


_OVERRIDABLE = ("acceleration", "potential", "potential_grad", "mass_matrix", "dissipation_matrix", "generalized_force", "actuation_force")


def _mlp_reason(field: nn.Module, what: str) -> str | None:
    if type(field) is not CholeskyField:
        return f"{what} is not the standard CholeskyField"
    mods = list(field.net)
    lin, act = mods[0::2], mods[1::2]
    if len(mods) % 2 != 1 or not all(type(m) is nn.Linear for m in lin) or not all(type(m) is nn.ELU and float(m.alpha) == 1.0 for m in act):
        return f"{what} MLP is not Linear/ELU(alpha=1) layers"
    return None


def unsupported_reason(model: object) -> str | None:
    """Why ``model`` cannot use the compiled path (``None`` when it can)."""
    if not isinstance(model, Lagrangian):
        return f"not a Lagrangian ({type(model).__name__})"
    for name in _OVERRIDABLE:  # a subclass changing the physics is not what the kernels implement
        if getattr(type(model), name) is not getattr(Lagrangian, name):
            return f"{type(model).__name__} overrides Lagrangian.{name}"
    if model.mass_kind not in COMPILED_MASS:
        return f"mass={model.mass_kind!r} (only {', '.join(repr(m) for m in COMPILED_MASS)} are compiled)"
    if model.mass_kind == "learned" and (why := _mlp_reason(model.mass_field, "learned inertia")) is not None:
        return why
    if model.n_u != 0:
        act = model.actuation
        if type(act) is not ConcaveMap or any(type(h) is not ICNN for h in act.heads):
            return "actuation is not the standard ConcaveMap(ICNN heads)"
        if len({tuple(lin.out_features for lin in h.inp) for h in act.heads}) != 1:
            return "actuation heads of different widths"
    pot = model.potential_hat
    if type(pot) is not ConvexPotential or type(pot.g) is not ICNN:
        return "potential is not the standard ConvexPotential(ICNN)"
    if pot.phi is not None and type(pot.phi) is not IResNet:
        return "invex map is not the standard IResNet"
    if (why := _mlp_reason(model.dissipation, "dissipation")) is not None:
        return why
    if any(p.device.type != "cpu" for p in model.parameters()):
        return "parameters are not on the CPU"
    return None


def supports_fast(model: object) -> bool:
    """Whether :func:`export_model` accepts ``model`` (the eval-mode check is the caller's)."""
    return unsupported_reason(model) is None


def _transposed(a: np.ndarray) -> np.ndarray:
    """``a`` with its last two axes swapped, contiguous."""
    return np.ascontiguousarray(np.swapaxes(a, -1, -2))


def _np(t: Tensor) -> np.ndarray:
    return t.detach().to(torch.float64).cpu().numpy()


def _icnn_arrays(g: ICNN, d: int) -> tuple[np.ndarray, ...]:
    """``(W [L,H,d], b [L,H], softplus(R) [L,H,H], softplus(w_out) [H], widths [L])`` of an ICNN."""
    widths = np.array([lin.out_features for lin in g.inp], np.int64)
    L, H = len(widths), int(widths.max())
    W, b, R = np.zeros((L, H, d)), np.zeros((L, H)), np.zeros((L, H, H))
    for l, lin in enumerate(g.inp):
        W[l, : widths[l]] = _np(lin.weight)
        b[l, : widths[l]] = _np(lin.bias)
    for l, Rl in enumerate(g.rec, start=1):
        R[l, : widths[l], : widths[l - 1]] = _np(torch.nn.functional.softplus(Rl))
    out = np.zeros(H)
    out[: widths[-1]] = _np(torch.nn.functional.softplus(g.out))
    return W, b, R, out, widths


def _mlp_arrays(field: CholeskyField | None) -> tuple[np.ndarray, ...]:
    """``(W [n_layers,H,H], b [n_layers,H], n_in, n_out)`` of a :class:`CholeskyField` (zero layers for ``None``)."""
    if field is None:
        return np.zeros((0, 1, 1)), np.zeros((0, 1)), np.zeros(0, np.int64), np.zeros(0, np.int64)
    lins = list(field.net)[0::2]
    Hd = max(max(m.in_features, m.out_features) for m in lins)
    W, b = np.zeros((len(lins), Hd, Hd)), np.zeros((len(lins), Hd))
    for k, m in enumerate(lins):
        W[k, : m.out_features, : m.in_features] = _np(m.weight)
        b[k, : m.out_features] = _np(m.bias)
    return W, b, np.array([m.in_features for m in lins], np.int64), np.array([m.out_features for m in lins], np.int64)


def _actuation_arrays(act: ConcaveMap | None, d: int) -> tuple[np.ndarray, ...]:
    """``(a [n_u,d], W [n_u,L,H,d], b [n_u,L,H], R [n_u,L,H,H], out [n_u,H], widths [L])`` of the concave map."""
    if act is None:
        return np.zeros((0, d)), np.zeros((0, 1, 1, d)), np.zeros((0, 1, 1)), np.zeros((0, 1, 1, 1)), np.zeros((0, 1)), np.ones(1, np.int64)
    heads = [_icnn_arrays(h, d) for h in act.heads]
    return (_np(act.a), np.stack([h[0] for h in heads]), np.stack([h[1] for h in heads]), np.stack([h[2] for h in heads]),
            np.stack([h[3] for h in heads]), heads[0][4])  # fmt: skip


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
    icnn_W, icnn_b, icnn_R, icnn_out, widths = _icnn_arrays(pot.g, d)
    L, H = icnn_b.shape
    if pot.phi is not None:  # rescaled exactly as IResNet.forward (in the model's dtype), then float64
        phi = pot.phi
        nb, width = len(phi.l1), phi.l1[0].out_features if len(phi.l1) else 1
        W1, b1, W2, b2 = np.zeros((nb, width, d)), np.zeros((nb, width)), np.zeros((nb, d, width)), np.zeros((nb, d))
        for k, (a, b) in enumerate(zip(phi.l1, phi.l2)):
            W1[k] = _np(a.weight / spectral_norm_estimate(a.weight).clamp_min(1.0))
            W2[k] = _np(b.weight * (phi.lip / spectral_norm_estimate(b.weight).clamp_min(phi.lip)))
            b1[k], b2[k] = _np(a.bias), _np(b.bias)
    else:
        W1, b1, W2, b2 = np.zeros((0, 1, d)), np.zeros((0, 1)), np.zeros((0, d, 1)), np.zeros((0, d))
    diss = _mlp_arrays(model.dissipation)
    mass = _mlp_arrays(model.mass_field if model.mass_kind == "learned" else None)
    act = _actuation_arrays(model.actuation if model.n_u else None, d)
    M = _np(model.mass_matrix(model.q_rest.detach()[None])[0])
    q_rest = _np(model.q_rest)
    y_rest = q_rest.copy()
    T = _transposed  # kernel layouts, see FastModel.kernel_args
    if W1.shape[0]:
        nb, width = b1.shape
        y_rest = phi_forward(q_rest, T(W1), b1, W2, b2, np.zeros((nb, d)), np.zeros((nb, width)), np.zeros(width))
    grad_rest = np.zeros(d)
    icnn_grad(y_rest, T(icnn_W), icnn_b, icnn_R, T(icnn_R), icnn_out, widths, np.zeros((L, H)), np.zeros((L, H)), np.zeros(H), np.zeros(H), grad_rest)
    return FastModel(
        d=d, n_u=int(model.n_u), mass_kind=model.mass_kind, M=M, M_inv=np.linalg.inv(M),
        exp_sV=float(torch.exp(model.s_V.detach().double())), exp_sM=float(torch.exp(model.s_M.detach().double())),
        c0=float(model.c0), eps=float(pot.eps), icnn_W=icnn_W, icnn_b=icnn_b, icnn_R=icnn_R, icnn_out=icnn_out,
        icnn_widths=widths, q_rest=q_rest, y_rest=y_rest, grad_rest=grad_rest, phi_W1=W1, phi_b1=b1, phi_W2=W2, phi_b2=b2,
        diss_W=diss[0], diss_b=diss[1], diss_in=diss[2], diss_out=diss[3], mass_W=mass[0], mass_b=mass[1], mass_in=mass[2],
        mass_out=mass[3], act_a=act[0], act_W=act[1], act_b=act[2], act_R=act[3], act_out=act[4], act_widths=act[5],
        tril_i=_np(model.dissipation.ii).astype(np.int64), tril_j=_np(model.dissipation.jj).astype(np.int64),
    )  # fmt: skip
