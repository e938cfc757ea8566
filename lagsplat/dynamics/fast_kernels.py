"""Compiled (numba) kernels of the fast rollout path: the ICNN / i-ResNet potential gradient and the dissipation
factor, in float64 (paper Eq. 8; the torch reference is
:meth:`lagsplat.models.lagrangian.Lagrangian.acceleration`). :mod:`lagsplat.dynamics.fast_loop` steps them,
:mod:`lagsplat.dynamics.fast` exports a model's weights and calls it.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["softplus", "elu", "elu_prime", "vecmat", "icnn_grad", "phi_forward", "phi_vjp", "grad_V", "mlp_forward", "tril_factor", "chol_factor", "workspace"]


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
    """``out[:m] = x[:n] @ A[:n, :m]`` for a 2-D ``A`` (row by row, contiguous inner loop)."""
    for j in range(m):
        out[j] = 0.0
    for i in range(n):
        xi = x[i]
        for j in range(m):
            out[j] += A[i, j] * xi


@njit(cache=True)
def icnn_grad(x, WT, b, R, RT, w_out, widths, z, hbuf, dh, dh2, gx):  # pragma: no cover - compiled
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
def mlp_forward(x, WT, b, n_in, n_out, a, a2, Z):  # pragma: no cover
    """ELU MLP ``x -> a[:n_out[-1]]`` (no activation after the last layer), the pre-activations kept in ``Z [n_layers,H]``.

    ``WT [n_layers,H_in,H_out]``: the layers' weights, transposed; ``a, a2 [H]``: work buffers.
    """
    nl = n_in.shape[0]
    for c in range(x.shape[0]):
        a[c] = x[c]
    for k in range(nl):
        no = n_out[k]
        for i in range(no):
            a2[i] = b[k, i]
        for j in range(n_in[k]):
            aj = a[j]
            for i in range(no):
                a2[i] += WT[k, j, i] * aj
        for i in range(no):
            Z[k, i] = a2[i]
            a[i] = elu(a2[i]) if k < nl - 1 else a2[i]


@njit(cache=True)
def tril_factor(raw, tril_i, tril_j, Lm):  # pragma: no cover
    """``Lm [d,d]``: lower-triangular factor from ``raw`` in ``tril_indices`` order, softplus on the diagonal."""
    d = Lm.shape[0]
    for r in range(d):
        for c in range(d):
            Lm[r, c] = 0.0
    for t in range(tril_i.shape[0]):
        r = tril_i[t]
        c = tril_j[t]
        Lm[r, c] = softplus(raw[t]) if r == c else raw[t]


@njit(cache=True)
def chol_factor(q, diss_WT, diss_b, diss_in, diss_out, tril_i, tril_j, a, a2, Z, Lm):  # pragma: no cover
    """``Lm [d,d] = L_C(q)``, the dissipation's Cholesky factor (:class:`CholeskyField`: ELU MLP, softplus diagonal).

    ``diss_WT [n_layers,H_in,H_out]``: the layers' weights, transposed; ``a, a2 [H]``, ``Z [n_layers,H]``: work buffers.
    """
    mlp_forward(q, diss_WT, diss_b, diss_in, diss_out, a, a2, Z)
    tril_factor(a, tril_i, tril_j, Lm)


@njit(cache=True)
def workspace(d, icnn_b, phi_b1, diss_b):  # pragma: no cover
    """Scratch arrays of :func:`position_terms` for states of dimension ``d``, sized by the padded layer widths.

    Returns the tuple ``(ws_z, ws_h, ws_dh, ws_dh2, ws_X, ws_Z, ws_t, a, a2, Zd)``:
    ICNN activations ``[L,H]`` x 2 and gradients ``[H]`` x 2, i-ResNet block
    inputs ``[nb,d]``, pre-activations ``[nb,width]`` and a ``[width]``
    buffer, two dissipation-MLP activations ``[max(Hd, d)]`` and its pre-activations ``[n_layers, max(Hd, d)]``.
    """
    L, H = icnn_b.shape[0], icnn_b.shape[1]
    nb, width = phi_b1.shape[0], phi_b1.shape[1]
    Hd = max(diss_b.shape[1], d)
    return (np.zeros((L, H)), np.zeros((L, H)), np.zeros(H), np.zeros(H), np.zeros((nb, d)), np.zeros((nb, width)), np.zeros(width),
            np.zeros(Hd), np.zeros(Hd), np.zeros((diss_b.shape[0], Hd)))  # fmt: skip
