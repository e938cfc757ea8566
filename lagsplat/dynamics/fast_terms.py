"""Compiled (numba) kernels of the fast rollout path for a position-dependent inertia and measured actuation.

The terms of paper Eq. 7 that :mod:`lagsplat.dynamics.fast_kernels` leaves out, all in float64 with
analytic derivatives (the torch reference is :meth:`lagsplat.models.lagrangian.Lagrangian.acceleration`):

* a learned inertia ``M(q) = e^{s_M} (L(q) L(q)^T + 0.1 I) / 1.1`` (``L`` the
  :class:`~lagsplat.models.inertia.CholeskyField` MLP, ELU, softplus diagonal) and its derivatives
  ``dM/dq_k`` by forward-mode differentiation through the MLP (:func:`inertia_terms`), which give the
  velocity-dependent inertial force ``dT/dq - (d(M qdot)/dq) qdot`` (:func:`inertial_force`);
* the actuation Jacobian of the concave chamber-volume map (paper Eq. 6),
  ``b(q)^T = e^{s_V} [a_j - grad g_j(q)]_j`` with ``g_j`` input-convex networks
  (:func:`actuation_jacobian`), so ``f_P = b(q)^T u``;
* a small in-place Cholesky solve for ``M(q) qddot = F`` (:func:`spd_solve`).

Everything here depends on the position only, except :func:`inertial_force`, so a rollout evaluates each
once per step (the velocity-Verlet scheme's second evaluation of a step and the first of the next share
the position).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from lagsplat.dynamics.fast_kernels import elu_prime, icnn_grad, mlp_forward, tril_factor

__all__ = ["sigmoid", "inertia_terms", "inertial_force", "actuation_jacobian", "spd_solve", "terms_workspace"]


@njit(cache=True)
def sigmoid(x):  # pragma: no cover - compiled
    """Derivative of torch's softplus (threshold 20) at a scalar."""
    if x > 20.0:
        return 1.0
    e = math.exp(x)
    return e / (e + 1.0)


@njit(cache=True)
def inertia_terms(q, exp_sM, WT, b, n_in, n_out, tril_i, tril_j, Z, a, a2, t, t2, Lm, dL, M, dM):  # pragma: no cover
    """``M(q)`` into ``M [d,d]`` and ``dM/dq_k`` into ``dM [d,d,d]`` (``dM[k]``), learned inertia (paper Eq. 7).

    ``WT [n_layers,H_in,H_out]``: the :class:`CholeskyField` layers' weights, transposed; ``Z [n_layers,H]``
    keeps the pre-activations, ``a, a2, t, t2 [H]`` are work buffers, ``Lm [d,d]`` and ``dL [d,d,d]`` receive
    the factor and its derivatives. ``M = e^{s_M} (L L^T + 0.1 I) / 1.1``,
    ``dM_k = e^{s_M} (dL_k L^T + L dL_k^T) / 1.1``.
    """
    d = q.shape[0]
    nl = n_in.shape[0]
    ntri = tril_i.shape[0]
    mlp_forward(q, WT, b, n_in, n_out, a, a2, Z)
    tril_factor(a, tril_i, tril_j, Lm)
    for kd in range(d):  # forward-mode derivative along q_kd
        for c in range(d):
            t[c] = 0.0
        t[kd] = 1.0
        for k in range(nl):
            no = n_out[k]
            for i in range(no):
                t2[i] = 0.0
            for j in range(n_in[k]):
                tj = t[j]
                for i in range(no):
                    t2[i] += WT[k, j, i] * tj
            for i in range(no):
                t[i] = elu_prime(Z[k, i]) * t2[i] if k < nl - 1 else t2[i]
        for r in range(d):
            for c in range(d):
                dL[kd, r, c] = 0.0
        for s in range(ntri):
            r, c = tril_i[s], tril_j[s]
            dL[kd, r, c] = sigmoid(Z[nl - 1, s]) * t[s] if r == c else t[s]
    scale = exp_sM / 1.1
    for r in range(d):
        for c in range(d):
            s0 = 0.0
            for m in range(d):
                s0 += Lm[r, m] * Lm[c, m]
            M[r, c] = scale * (s0 + (0.1 if r == c else 0.0))
    for kd in range(d):
        for r in range(d):
            for c in range(d):
                s0 = 0.0
                for m in range(d):
                    s0 += dL[kd, r, m] * Lm[c, m] + Lm[r, m] * dL[kd, c, m]
                dM[kd, r, c] = scale * s0


@njit(cache=True)
def inertial_force(dM, v, w, out):  # pragma: no cover
    """``out += dT/dq - (d(M v)/dq) v`` for ``dM [d,d,d]`` (``dM[k] = dM/dq_k``), velocity ``v [d]``, buffer ``w [d]``.

    ``dT/dq_k = 1/2 v^T dM_k v``; ``((d(M v)/dq) v)_r = sum_k (dM_k v)_r v_k``.
    """
    d = v.shape[0]
    for k in range(d):
        s = 0.0
        for r in range(d):
            wr = 0.0
            for c in range(d):
                wr += dM[k, r, c] * v[c]
            w[r] = wr
            s += v[r] * wr
        out[k] += 0.5 * s
        for r in range(d):
            out[r] -= w[r] * v[k]


@njit(cache=True)
def actuation_jacobian(q, exp_sV, act_a, act_WT, act_b, act_R, act_RT, act_out, act_widths, z, hbuf, dh, dh2, g, Bq):  # pragma: no cover
    """``Bq [n_u,d] = e^{s_V} (a_j - grad g_j(q))``, rows of the actuation force ``f_P = Bq^T u`` (paper Eq. 6).

    One input-convex head ``g_j`` per channel: ``act_WT [n_u,L,d,H]``, ``act_b [n_u,L,H]``,
    ``act_R``/``act_RT [n_u,L,H,H]``, ``act_out [n_u,H]``; ``z, hbuf [L,H]``, ``dh, dh2 [H]``, ``g [d]`` workspace.
    """
    n_u, d = act_a.shape
    for j in range(n_u):
        icnn_grad(q, act_WT[j], act_b[j], act_R[j], act_RT[j], act_out[j], act_widths, z, hbuf, dh, dh2, g)
        for c in range(d):
            Bq[j, c] = exp_sV * (act_a[j, c] - g[c])


@njit(cache=True)
def spd_solve(A, rhs, Lw, out):  # pragma: no cover
    """``out = A^-1 rhs`` for a small SPD ``A [d,d]`` by Cholesky (``Lw [d,d]`` workspace); ``False`` (and NaN in
    ``out``) when ``A`` is not positive definite in floating point."""
    d = rhs.shape[0]
    for j in range(d):
        s = A[j, j]
        for m in range(j):
            s -= Lw[j, m] * Lw[j, m]
        if not s > 0.0:
            for c in range(d):
                out[c] = np.nan
            return False
        Lw[j, j] = math.sqrt(s)
        for i in range(j + 1, d):
            s2 = A[i, j]
            for m in range(j):
                s2 -= Lw[i, m] * Lw[j, m]
            Lw[i, j] = s2 / Lw[j, j]
    for i in range(d):  # L y = rhs
        s = rhs[i]
        for m in range(i):
            s -= Lw[i, m] * out[m]
        out[i] = s / Lw[i, i]
    for i in range(d - 1, -1, -1):  # L^T x = y
        s = out[i]
        for m in range(i + 1, d):
            s -= Lw[m, i] * out[m]
        out[i] = s / Lw[i, i]
    return True


@njit(cache=True)
def terms_workspace(d, mass_b, act_b):  # pragma: no cover
    """Buffers of :func:`inertia_terms` and :func:`actuation_jacobian` for states of dimension ``d``.

    Returns ``(Z, a, a2, t, t2, Lm, dL, M, dM, az, ah, adh, adh2, ag, Bq, Lw, w)``.
    """
    nl, Hm = mass_b.shape[0], max(mass_b.shape[1], d)
    n_u, La, Ha = act_b.shape[0], act_b.shape[1], act_b.shape[2]
    return (np.zeros((nl, Hm)), np.zeros(Hm), np.zeros(Hm), np.zeros(Hm), np.zeros(Hm), np.zeros((d, d)), np.zeros((d, d, d)),
            np.zeros((d, d)), np.zeros((d, d, d)), np.zeros((La, Ha)), np.zeros((La, Ha)), np.zeros(Ha), np.zeros(Ha), np.zeros(d),
            np.zeros((n_u, d)), np.zeros((d, d)), np.zeros(d))  # fmt: skip
