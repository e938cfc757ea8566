"""Compiled kernels of the soft-robot model: backbone kinematics, accelerations, frame-by-frame integration (numba).

Part of :mod:`lagsplat.synth.continuum_robot` (its docstring describes the model).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, inline="always")
def sinc3(x: float) -> tuple[float, float, float]:
    """``S(x) = sin x / x`` and its first two derivatives (series for ``|x| < 0.1``)."""
    if abs(x) < 0.1:
        x2 = x * x
        s0 = 1.0 - x2 / 6.0 * (1.0 - x2 / 20.0 * (1.0 - x2 / 42.0 * (1.0 - x2 / 72.0)))
        s1 = x * (-1.0 / 3.0 + x2 * (1.0 / 30.0 + x2 * (-1.0 / 840.0 + x2 / 45360.0)))
        s2 = -1.0 / 3.0 + x2 * (1.0 / 10.0 + x2 * (-1.0 / 168.0 + x2 / 6480.0))
        return s0, s1, s2
    sn, cs = math.sin(x), math.cos(x)
    return sn / x, cs / x - sn / (x * x), -sn / x - 2.0 * cs / (x * x) + 2.0 * sn / (x * x * x)


@njit(cache=True)
def backbone_kinematics(q, qd, L0, N):  # pragma: no cover - compiled; checked against numpy in the tests
    """Node positions ``r`` [n N], Jacobians ``J`` [n N, d] and convective accelerations ``a`` [n N] (complex)."""
    n = L0.shape[0]
    d = 2 * n
    nl = n * N
    r = np.empty(nl, np.complex128)
    J = np.empty((nl, d), np.complex128)
    a = np.empty(nl, np.complex128)
    accr = 0j
    accJ = np.zeros(d, np.complex128)
    acca = 0j
    Phi = 0.0
    Phid = 0.0
    for i in range(n):
        th, ep = q[2 * i], q[2 * i + 1]
        thd, epd = qd[2 * i], qd[2 * i + 1]
        x = th / (2.0 * N)
        xd = thd / (2.0 * N)
        S, S1, S2 = sinc3(x)
        lnode = L0[i] / N
        ell = lnode * (1.0 + ep) * S
        elld = lnode * (epd * S + (1.0 + ep) * S1 * xd)
        elldd = lnode * (2.0 * epd * S1 * xd + (1.0 + ep) * S2 * xd * xd)
        dell_dth = lnode * (1.0 + ep) * S1 / (2.0 * N)
        dell_dep = lnode * S
        for j in range(N):
            frac = (j + 0.5) / N
            phi = Phi + th * frac
            phid = Phid + thd * frac
            E = complex(math.cos(phi), -math.sin(phi))  # exp(-i phi)
            iE = 1j * E
            accr += ell * iE
            # d(phi)/d(theta_k) = 1 for earlier segments, frac for this one.
            for k in range(i):
                accJ[2 * k] += ell * E
            accJ[2 * i] += frac * ell * E + dell_dth * iE
            accJ[2 * i + 1] += dell_dep * iE
            acca += (elldd * iE + 2.0 * elld * phid * E) - 1j * ell * phid * phid * E
            row = i * N + j
            r[row] = accr
            for c in range(d):
                J[row, c] = accJ[c]
            a[row] = acca
        Phi += th
        Phid += thd
    return r, J, a


@njit(cache=True)
def robot_acceleration(q, qd, Pc, L0, N, mass, kdiag, D, B, g):  # pragma: no cover - compiled
    """``qddot`` from the Euler-Lagrange equations (module docstring)."""
    _, J, a = backbone_kinematics(q, qd, L0, N)
    d = q.shape[0]
    nl = mass.shape[0]
    M = np.zeros((d, d))
    f = np.zeros(d)
    for c in range(d):
        f[c] = -kdiag[c] * q[c]
        for e in range(d):
            f[c] -= D[c, e] * qd[e]
        for e in range(Pc.shape[0]):
            f[c] += B[c, e] * Pc[e]
    for k in range(nl):
        m = mass[k]
        for c in range(d):
            Jc = J[k, c]
            f[c] += m * (g * Jc.imag - (Jc.real * a[k].real + Jc.imag * a[k].imag))
            for e in range(c, d):
                M[c, e] += m * (Jc.real * J[k, e].real + Jc.imag * J[k, e].imag)
    # Cholesky solve of the symmetric positive definite M (upper triangle filled).
    Lc = np.zeros((d, d))
    for c in range(d):
        acc = M[c, c]
        for e in range(c):
            acc -= Lc[c, e] * Lc[c, e]
        Lc[c, c] = math.sqrt(acc)
        for r in range(c + 1, d):
            acc = M[c, r]
            for e in range(c):
                acc -= Lc[r, e] * Lc[c, e]
            Lc[r, c] = acc / Lc[c, c]
    z = np.empty(d)
    for c in range(d):
        acc = f[c]
        for e in range(c):
            acc -= Lc[c, e] * z[e]
        z[c] = acc / Lc[c, c]
    x = np.empty(d)
    for c in range(d - 1, -1, -1):
        acc = z[c]
        for e in range(c + 1, d):
            acc -= Lc[e, c] * x[e]
        x[c] = acc / Lc[c, c]
    return x


@njit(cache=True)
def integrate_robot(y0, P_half, n_frames, n_sub, h, L0, N, mass, kdiag, D, B, g):  # pragma: no cover - compiled
    """RK4 with ``n_sub`` steps per frame; ``P_half[k]`` is the pressure at ``t = k h / 2``."""
    d = y0.shape[0] // 2
    Y = np.empty((n_frames, 2 * d))
    q, v = y0[:d].copy(), y0[d:].copy()
    qs, vs = np.empty(d), np.empty(d)
    dq, dv = np.zeros(d), np.zeros(d)
    kq, kv = np.zeros(d), np.zeros(d)
    Y[0] = y0
    s = 0
    for i in range(1, n_frames):
        for _ in range(n_sub):
            for stage in range(4):
                if stage == 0:
                    qs[:], vs[:] = q, v
                    P = P_half[2 * s]
                elif stage == 3:
                    qs[:], vs[:] = q + h * kq, v + h * kv
                    P = P_half[2 * s + 2]
                else:
                    qs[:], vs[:] = q + 0.5 * h * kq, v + 0.5 * h * kv
                    P = P_half[2 * s + 1]
                kq = vs.copy()
                kv = robot_acceleration(qs, vs, P, L0, N, mass, kdiag, D, B, g)
                w = 1.0 if (stage == 0 or stage == 3) else 2.0
                dq += w * kq
                dv += w * kv
            q += (h / 6.0) * dq
            v += (h / 6.0) * dv
            dq[:] = 0.0
            dv[:] = 0.0
            s += 1
        Y[i, :d] = q
        Y[i, d:] = v
    return Y


