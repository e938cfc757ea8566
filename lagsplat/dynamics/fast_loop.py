"""The compiled (numba) velocity-Verlet loop of the fast rollout path and its acceleration (paper Eq. 7, Eq. 8).

``M(q) qddot = dT/dq - (d(M qdot)/dq) qdot - dV/dq - C(q) qdot + f_ext + b(q)^T u``, with the position
terms of :mod:`lagsplat.dynamics.fast_kernels` (``dV/dq``, the dissipation factor) and
:mod:`lagsplat.dynamics.fast_terms` (a learned ``M(q)`` and its derivatives, the actuation Jacobian), each
evaluated once per position. A constant inertia (``mass_in`` empty) takes ``M_inv``; a model without actuation
has ``n_u = 0`` (zero-width ``Ua``/``Ub`` and ``act_*``). The torch reference is
:meth:`lagsplat.models.lagrangian.Lagrangian.acceleration` and :func:`lagsplat.dynamics.integrators.verlet_step`.

The weights come in the order of :attr:`lagsplat.dynamics.fast_export.FastModel.kernel_args` (``*W`` below).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from lagsplat.dynamics.fast_kernels import chol_factor, grad_V, workspace
from lagsplat.dynamics.fast_terms import actuation_jacobian, inertia_terms, inertial_force, spd_solve, terms_workspace

__all__ = ["position_terms", "accel", "rollout_kernel", "accel_kernel"]


@njit(cache=True)
def position_terms(q, exp_sV, exp_sM, eps, icnn_WT, icnn_b, icnn_R, icnn_RT, icnn_out, icnn_widths, y_rest, grad_rest, phi_W1T, phi_b1, phi_W2, phi_b2, diss_WT, diss_b, diss_in, diss_out, tril_i, tril_j, mass_WT, mass_b, mass_in, mass_out, act_a, act_WT, act_b, act_R, act_RT, act_out, act_widths, ws, tw, gV, Lm):  # pragma: no cover
    """The position-only terms at ``q [d]``, in place: ``gV = dV/dq``, ``Lm = L_C(q)``, and in ``tw``
    (:func:`~lagsplat.dynamics.fast_terms.terms_workspace`) ``M(q)``, ``dM/dq`` (learned inertia) and ``b(q)^T`` (actuation)."""
    ws_z, ws_h, ws_dh, ws_dh2, ws_X, ws_Z, ws_t, a, a2, Zd = ws
    Z, ma, ma2, mt, mt2, mL, mdL, M, dM, az, ah, adh, adh2, ag, Bq, Lw, w = tw
    grad_V(q, exp_sV, eps, icnn_WT, icnn_b, icnn_R, icnn_RT, icnn_out, icnn_widths, y_rest, grad_rest, phi_W1T, phi_b1, phi_W2, phi_b2, ws_z, ws_h, ws_dh, ws_dh2, ws_X, ws_Z, ws_t, gV)
    chol_factor(q, diss_WT, diss_b, diss_in, diss_out, tril_i, tril_j, a, a2, Zd, Lm)
    if mass_in.shape[0] > 0:
        inertia_terms(q, exp_sM, mass_WT, mass_b, mass_in, mass_out, tril_i, tril_j, Z, ma, ma2, mt, mt2, mL, mdL, M, dM)
    if act_a.shape[0] > 0:
        actuation_jacobian(q, exp_sV, act_a, act_WT, act_b, act_R, act_RT, act_out, act_widths, az, ah, adh, adh2, ag, Bq)


@njit(cache=True)
def accel(gV, Lm, v, f, u, M_inv, exp_sM, c0, learned, M, dM, Bq, Lw, w, tmp, force, out):  # pragma: no cover
    """``out = M^-1 (-gV - C v + f + b^T u (+ dT/dq - (d(M v)/dq) v))`` with ``C v = e^{s_M} L (L^T v) + c0 v`` (paper
    Eq. 7); the inertia is ``M_inv`` (constant) or, with ``learned``, ``M(q)`` with its derivatives ``dM`` (Cholesky
    solve, work buffers ``Lw, w``); ``Bq = b(q)^T`` rows. Returns ``False`` (NaN in ``out``) when the learned ``M(q)``
    is not positive definite."""
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
        fr = -gV[r] - (exp_sM * s + c0 * v[r]) + f[r]
        for j in range(u.shape[0]):
            fr += Bq[j, r] * u[j]
        force[r] = fr
    if learned:
        inertial_force(dM, v, w, force)
        return spd_solve(M, force, Lw, out)
    for r in range(d):
        s = 0.0
        for c in range(d):
            s += M_inv[r, c] * force[c]
        out[r] = s
    return True


@njit(cache=True)
def rollout_kernel(q0, v0, f, Ua, Ub, h, n, M_inv, exp_sV, exp_sM, c0, eps, icnn_WT, icnn_b, icnn_R, icnn_RT, icnn_out, icnn_widths, y_rest, grad_rest, phi_W1T, phi_b1, phi_W2, phi_b2, diss_WT, diss_b, diss_in, diss_out, tril_i, tril_j, mass_WT, mass_b, mass_in, mass_out, act_a, act_WT, act_b, act_R, act_RT, act_out, act_widths):  # pragma: no cover
    """Velocity-Verlet rollouts (paper Eq. 8) of ``B`` trajectories; returns ``(q, v) [B,n,d]``.

    Per step ``i``: ``a1 = a(q, v, Ua[:, i])``; ``vh = v + h/2 a1``; ``q1 = q + h vh``;
    ``a2 = a(q1, vh, Ub[:, i])``; ``v1 = vh + h/2 a2`` (``Ua, Ub [B,n-1,n_u]``: the actuation at the two
    evaluations; equal for a zero-order hold). A trajectory whose state turns non-finite, or whose learned
    inertia stops being positive definite, is NaN from that step on.
    """
    B, d = q0.shape
    qs = np.empty((B, n, d))
    vs = np.empty((B, n, d))
    ws = workspace(d, icnn_b, phi_b1, diss_b)
    tw = terms_workspace(d, mass_b, act_b)
    M, dM, Bq, Lw, w = tw[7], tw[8], tw[14], tw[15], tw[16]  # in terms_workspace's documented order
    learned = mass_in.shape[0] > 0
    Lm = np.zeros((d, d))
    gV, tmp, force, acc = np.zeros(d), np.zeros(d), np.zeros(d), np.zeros(d)
    q, v, vh = np.zeros(d), np.zeros(d), np.zeros(d)
    for b in range(B):
        for c in range(d):
            q[c] = q0[b, c]
            v[c] = v0[b, c]
            qs[b, 0, c] = q[c]
            vs[b, 0, c] = v[c]
        position_terms(q, exp_sV, exp_sM, eps, icnn_WT, icnn_b, icnn_R, icnn_RT, icnn_out, icnn_widths, y_rest, grad_rest, phi_W1T, phi_b1, phi_W2, phi_b2, diss_WT, diss_b, diss_in, diss_out, tril_i, tril_j, mass_WT, mass_b, mass_in, mass_out, act_a, act_WT, act_b, act_R, act_RT, act_out, act_widths, ws, tw, gV, Lm)
        for i in range(1, n):
            ok = accel(gV, Lm, v, f[b], Ua[b, i - 1], M_inv, exp_sM, c0, learned, M, dM, Bq, Lw, w, tmp, force, acc)
            for c in range(d):
                vh[c] = v[c] + 0.5 * h * acc[c]
                q[c] = q[c] + h * vh[c]
            position_terms(q, exp_sV, exp_sM, eps, icnn_WT, icnn_b, icnn_R, icnn_RT, icnn_out, icnn_widths, y_rest, grad_rest, phi_W1T, phi_b1, phi_W2, phi_b2, diss_WT, diss_b, diss_in, diss_out, tril_i, tril_j, mass_WT, mass_b, mass_in, mass_out, act_a, act_WT, act_b, act_R, act_RT, act_out, act_widths, ws, tw, gV, Lm)
            ok = accel(gV, Lm, vh, f[b], Ub[b, i - 1], M_inv, exp_sM, c0, learned, M, dM, Bq, Lw, w, tmp, force, acc) and ok
            finite = ok
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
def accel_kernel(q, v, f, u, M_inv, exp_sV, exp_sM, c0, eps, icnn_WT, icnn_b, icnn_R, icnn_RT, icnn_out, icnn_widths, y_rest, grad_rest, phi_W1T, phi_b1, phi_W2, phi_b2, diss_WT, diss_b, diss_in, diss_out, tril_i, tril_j, mass_WT, mass_b, mass_in, mass_out, act_a, act_WT, act_b, act_R, act_RT, act_out, act_widths):  # pragma: no cover
    """``(qddot, dV/dq)`` at ``B`` states ``q, v [B,d]`` under force ``f [B,d]`` and actuation ``u [B,n_u]``."""
    B, d = q.shape
    out = np.empty((B, d))
    gout = np.empty((B, d))
    ws = workspace(d, icnn_b, phi_b1, diss_b)
    tw = terms_workspace(d, mass_b, act_b)
    M, dM, Bq, Lw, w = tw[7], tw[8], tw[14], tw[15], tw[16]  # in terms_workspace's documented order
    learned = mass_in.shape[0] > 0
    Lm = np.zeros((d, d))
    gV, tmp, force, acc = np.zeros(d), np.zeros(d), np.zeros(d), np.zeros(d)
    for b in range(B):
        qb = q[b].copy()
        position_terms(qb, exp_sV, exp_sM, eps, icnn_WT, icnn_b, icnn_R, icnn_RT, icnn_out, icnn_widths, y_rest, grad_rest, phi_W1T, phi_b1, phi_W2, phi_b2, diss_WT, diss_b, diss_in, diss_out, tril_i, tril_j, mass_WT, mass_b, mass_in, mass_out, act_a, act_WT, act_b, act_R, act_RT, act_out, act_widths, ws, tw, gV, Lm)
        accel(gV, Lm, v[b], f[b], u[b], M_inv, exp_sM, c0, learned, M, dM, Bq, Lw, w, tmp, force, acc)
        for c in range(d):
            out[b, c] = acc[c]
            gout[b, c] = gV[c]
    return out, gout
