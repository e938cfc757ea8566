"""Compiled (numba) kernels of the fast rollout path: the ICNN / i-ResNet potential gradient, the dissipation
factor, the acceleration and the velocity-Verlet loop, all in float64 (paper Eq. 8; the torch reference is
:meth:`lagsplat.models.lagrangian.Lagrangian.acceleration`). :mod:`lagsplat.dynamics.fast` exports a model's
weights and calls them.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["softplus", "elu", "elu_prime", "vecmat", "icnn_grad", "phi_forward", "phi_vjp", "grad_V", "chol_factor", "accel", "workspace", "position_terms", "rollout_kernel", "accel_kernel"]


@njit(cache=True)
def softplus(x):  # pragma: no cover - compiled
    """Numerically stable ``log(1 + e^x)`` of a scalar."""
    return x if x > 20.0 else math.log1p(math.exp(x))


@njit(cache=True)
def elu(x):  # pragma: no cover - compiled
    """ELU of a scalar (alpha 1)."""
    return x if x > 0.0 else math.expm1(x)


@njit(cache=True)
def elu_prime(x):  # pragma: no cover - compiled
    """Derivative of :func:`elu` at a scalar."""
    return 1.0 if x > 0.0 else math.exp(x)


@njit(cache=True)
def vecmat(x, A, n, m, out):  # pragma: no cover - compiled
    """``out[:m] = x[:n] @ A[:n, :m]`` without allocation."""
    """``out[:m] = x[:n] @ A[:n, :m]`` for a 2-D ``A`` (row by row, contiguous inner loop)."""
    for j in range(m):
        out[j] = 0.0
    for i in range(n):
        xi = x[i]
        for j in range(m):
            out[j] += A[i, j] * xi


@njit(cache=True)
def icnn_grad(x, WT, b, R, RT, w_out, widths, z, hbuf, dh, dh2, gx):  # pragma: no cover - compiled
    """Gradient of the ICNN potential at ``x`` (back-propagated through the layers in the given work buffers)."""
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
            vecmat(dh, R[l], n, m, dh2)
            for j in range(m):
                dh[j] = dh2[j]


@njit(cache=True)
def phi_forward(x, W1T, b1, W2, b2, X, Z, t):  # pragma: no cover - compiled
    """Forward pass of the i-ResNet ``phi`` (invex potential), keeping the activations for :func:`phi_vjp`."""
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
            t[i] = elu(Z[k, i])
        for c in range(d):
            s = b2[k, c]
            for i in range(width):
                s += W2[k, c, i] * t[i]
            y[c] = X[k, c] + s
    return y


@njit(cache=True)
def phi_vjp(g, W1T, W2, Z, t):  # pragma: no cover - compiled
    """Vector-Jacobian product ``g^T d phi / dx`` through the i-ResNet."""
    """In place ``g <- Dphi(x)^T g`` from the stored pre-activations ``Z`` (``t [width]`` workspace)."""
    nb = W1T.shape[0]
    width = W1T.shape[2]
    d = g.shape[0]
    for k in range(nb - 1, -1, -1):
        # block y = x + W2 elu(W1 x + b1) + b2:  g_x = g_y + W1^T (elu'(z) * (W2^T g_y))
        vecmat(g, W2[k], d, width, t)
        for i in range(width):
            t[i] *= elu_prime(Z[k, i])
        for c in range(d):
            s = 0.0
            for i in range(width):
                s += W1T[k, c, i] * t[i]
            g[c] += s


@njit(cache=True)
def grad_V(q, exp_sV, eps, icnn_WT, icnn_b, icnn_R, icnn_RT, icnn_out, icnn_widths, y_rest, grad_rest, phi_W1T, phi_b1, phi_W2, phi_b2, ws_z, ws_h, ws_dh, ws_dh2, ws_X, ws_Z, ws_t, gq):  # pragma: no cover
    """Gradient of the potential ``V(q)`` (convex or invex, Bregman-anchored at the rest state), written to ``gq``."""
    """``gq[:] = dV/dq(q)`` (paper §3.3; App. A.2 (A2)): ``e^{s_V} Dphi^T (grad g(y) - grad g(y*) + eps (y - y*))``."""
    d = q.shape[0]
    if phi_W1T.shape[0] > 0:
        y = phi_forward(q, phi_W1T, phi_b1, phi_W2, phi_b2, ws_X, ws_Z, ws_t)
    else:
        y = q.copy()
    icnn_grad(y, icnn_WT, icnn_b, icnn_R, icnn_RT, icnn_out, icnn_widths, ws_z, ws_h, ws_dh, ws_dh2, gq)
    for c in range(d):
        gq[c] = gq[c] - grad_rest[c] + eps * (y[c] - y_rest[c])
    if phi_W1T.shape[0] > 0:
        phi_vjp(gq, phi_W1T, phi_W2, ws_Z, ws_t)
    for c in range(d):
        gq[c] *= exp_sV


@njit(cache=True)
def chol_factor(q, diss_WT, diss_b, diss_in, diss_out, tril_i, tril_j, a, a2, Lm):  # pragma: no cover
    """The dissipation network's Cholesky factor ``L(q)`` (``C = e^{s_M} L L^T + c0 I``), written to ``Lm``."""
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
                a[i] = elu(a2[i])
        else:
            for i in range(no):
                a[i] = a2[i]
    for r in range(d):
        for c in range(d):
            Lm[r, c] = 0.0
    for t in range(tril_i.shape[0]):
        r = tril_i[t]
        c = tril_j[t]
        Lm[r, c] = softplus(a[t]) if r == c else a[t]


@njit(cache=True)
def accel(gV, Lm, v, f, M_inv, exp_sM, c0, tmp, force, out):  # pragma: no cover
    """Acceleration ``M^-1 (f - dV/dq - C(q) v)``, written to ``out``."""
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
def workspace(d, icnn_b, phi_b1, diss_b):  # pragma: no cover
    """Work buffers of one state for the kernels above."""
    """Scratch arrays of :func:`position_terms` for states of dimension ``d``, sized by the padded layer widths.

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
def position_terms(q, exp_sV, eps, icnn_WT, icnn_b, icnn_R, icnn_RT, icnn_out, icnn_widths, y_rest, grad_rest, phi_W1T, phi_b1, phi_W2, phi_b2, diss_WT, diss_b, diss_in, diss_out, tril_i, tril_j, ws, gV, Lm):  # pragma: no cover
    """The position-dependent terms of one state: ``dV/dq`` into ``gV`` and the dissipation factor into ``Lm``."""
    """The position-only terms at ``q [d]``: ``gV = dV/dq(q)`` and ``Lm = L(q)`` (in place; ``ws`` from :func:`workspace`)."""
    ws_z, ws_h, ws_dh, ws_dh2, ws_X, ws_Z, ws_t, a, a2 = ws
    grad_V(q, exp_sV, eps, icnn_WT, icnn_b, icnn_R, icnn_RT, icnn_out, icnn_widths, y_rest, grad_rest, phi_W1T, phi_b1, phi_W2, phi_b2, ws_z, ws_h, ws_dh, ws_dh2, ws_X, ws_Z, ws_t, gV)
    chol_factor(q, diss_WT, diss_b, diss_in, diss_out, tril_i, tril_j, a, a2, Lm)


@njit(cache=True)
def rollout_kernel(q0, v0, f, h, n, M_inv, exp_sV, exp_sM, c0, eps, icnn_WT, icnn_b, icnn_R, icnn_RT, icnn_out, icnn_widths, y_rest, grad_rest, phi_W1T, phi_b1, phi_W2, phi_b2, diss_WT, diss_b, diss_in, diss_out, tril_i, tril_j):  # pragma: no cover
    """Velocity-Verlet rollout of ``n`` states of step ``h`` from ``(q0, v0)`` under constant force ``f`` (paper Eq. 8); returns ``(q, v)``."""
    """Velocity-Verlet rollouts (paper Eq. 8) of ``B`` trajectories; returns ``(q, v) [B,n,d]``.

    Per step: ``a1 = a(q, v)``; ``vh = v + h/2 a1``; ``q1 = q + h vh``;
    ``a2 = a(q1, vh)``; ``v1 = vh + h/2 a2``. A trajectory whose state turns
    non-finite is NaN from that step on.
    """
    B, d = q0.shape
    qs = np.empty((B, n, d))
    vs = np.empty((B, n, d))
    ws = workspace(d, icnn_b, phi_b1, diss_b)
    Lm = np.zeros((d, d))
    gV, tmp, force, acc = np.zeros(d), np.zeros(d), np.zeros(d), np.zeros(d)
    q, v, vh = np.zeros(d), np.zeros(d), np.zeros(d)
    for b in range(B):
        for c in range(d):
            q[c] = q0[b, c]
            v[c] = v0[b, c]
            qs[b, 0, c] = q[c]
            vs[b, 0, c] = v[c]
        position_terms(q, exp_sV, eps, icnn_WT, icnn_b, icnn_R, icnn_RT, icnn_out, icnn_widths, y_rest, grad_rest, phi_W1T, phi_b1, phi_W2, phi_b2, diss_WT, diss_b, diss_in, diss_out, tril_i, tril_j, ws, gV, Lm)
        for i in range(1, n):
            accel(gV, Lm, v, f[b], M_inv, exp_sM, c0, tmp, force, acc)
            for c in range(d):
                vh[c] = v[c] + 0.5 * h * acc[c]
                q[c] = q[c] + h * vh[c]
            position_terms(q, exp_sV, eps, icnn_WT, icnn_b, icnn_R, icnn_RT, icnn_out, icnn_widths, y_rest, grad_rest, phi_W1T, phi_b1, phi_W2, phi_b2, diss_WT, diss_b, diss_in, diss_out, tril_i, tril_j, ws, gV, Lm)
            accel(gV, Lm, vh, f[b], M_inv, exp_sM, c0, tmp, force, acc)
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
def accel_kernel(q, v, f, M_inv, exp_sV, exp_sM, c0, eps, icnn_WT, icnn_b, icnn_R, icnn_RT, icnn_out, icnn_widths, y_rest, grad_rest, phi_W1T, phi_b1, phi_W2, phi_b2, diss_WT, diss_b, diss_in, diss_out, tril_i, tril_j):  # pragma: no cover
    """Acceleration at a batch of states ``(q, v)`` under force ``f``."""
    """``(qddot, dV/dq)`` at ``B`` states, each ``[B,d]``."""
    B, d = q.shape
    out = np.empty((B, d))
    gout = np.empty((B, d))
    ws = workspace(d, icnn_b, phi_b1, diss_b)
    Lm = np.zeros((d, d))
    gV, tmp, force, acc = np.zeros(d), np.zeros(d), np.zeros(d), np.zeros(d)
    for b in range(B):
        qb = q[b].copy()
        position_terms(qb, exp_sV, eps, icnn_WT, icnn_b, icnn_R, icnn_RT, icnn_out, icnn_widths, y_rest, grad_rest, phi_W1T, phi_b1, phi_W2, phi_b2, diss_WT, diss_b, diss_in, diss_out, tril_i, tril_j, ws, gV, Lm)
        accel(gV, Lm, v[b], f[b], M_inv, exp_sM, c0, tmp, force, acc)
        for c in range(d):
            out[b, c] = acc[c]
            gout[b, c] = gV[c]
    return out, gout
