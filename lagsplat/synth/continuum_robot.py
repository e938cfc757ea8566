"""An offline surrogate of the Krauss pneumatic soft continuum robot (one or two segments).

Writes a clip in the layout of the published soft-robot recordings (Krauss et
al., processed NPZ; the team notes ``reference_implementation.md`` section
2.1-2.3, ``baselines.md`` A.1): ``images`` ``(T, 3, 32, 32)`` float32 RGB in
[0, 1] (exact multiples of 1/255), one ``(T,)`` pressure vector per chamber,
``p1, p2`` for one segment and ``p1..p4`` for two (the same keys as the real
files: the one-segment recording holds ``p1, p2`` only), gauge pressures divided
by 101 325 Pa, 59.94 fps (``dt = 1001/60000`` s). The clip opens with a static
head (pressures zero, robot at rest), is driven by smooth random pressures in
the 0.04-2 Hz band (paper Section 4.4) and ends with a depressurised
free-oscillation tail. Its physics (natural frequencies, damping ratios, rest
state, the linearisation) is known exactly and written to a sidecar JSON,
``<file>.npz.json``, so the soft-robot benchmark can run here without the
4.5 GB download.

Physics
-------
A planar piecewise-constant-curvature (PCC) chain hanging from a fixed mount,
the standard reduced model of soft continuum arms (Webster & Jones, "Design
and kinematic modeling of constant curvature continuum robots: a review",
IJRR 2010; Della Santina et al., "Model-based dynamic feedback control of a
planar soft robot", IJRR 2020). Segment ``i`` has rest length ``L0_i`` (m),
total bending angle ``theta_i`` (rad; curvature ``kappa_i = theta_i / L_i``)
and axial strain ``eps_i`` (length ``L_i = L0_i (1 + eps_i)``), so the
configuration is::

    q = (theta_1, eps_1[, theta_2, eps_2])        (d = 2 per segment)

Kinematics (image coordinates, metres: ``x`` right, ``y`` down, so gravity is
``+y``; a point is the complex number ``x + i y``). The tangent angle from the
downward vertical at arc fraction ``s`` of segment ``i`` is
``phi(s) = Phi_i + theta_i s`` with ``Phi_i = theta_1 + ... + theta_{i-1}``,
and the unit tangent is ``(sin phi, cos phi) = i exp(-i phi)``. Each segment is
split into ``N`` equal sub-arcs; the chord of sub-arc ``j`` (``j = 1..N``) is
exactly::

    v_ij = l_i i exp(-i phi_ij),   l_i = (L0_i / N) (1 + eps_i) S(theta_i / 2N),
    phi_ij = Phi_i + theta_i (j - 1/2) / N,          S(x) = sin(x) / x,

so the node positions ``r_k`` (cumulative sums of the chords from the mount)
lie exactly on the PCC arcs for any ``theta`` (``S`` is evaluated by its
series near 0, so the straight configuration is regular). Positive
``theta_i`` bends segment ``i`` to the right of the image (its tip moves to
``+x`` when hanging).

Mass: each segment's mass ``m_i`` is lumped on its ``N + 1`` nodes by the
trapezoidal rule (``m_i / N`` inside, ``m_i / 2N`` at both ends; the half
node on the mount never moves), plus a point mass ``m_tip_i`` at each segment
tip (the rigid connector ring between two segments, the end cap). With the
node Jacobians ``J_k = dr_k/dq`` (complex, ``[d]``)::

    T = 1/2 qdot^T M(q) qdot,          M(q) = sum_k m_k Re(J_k^H J_k),
    V = 1/2 sum_i (k_b,i theta_i^2 + k_a,i eps_i^2) - g sum_k m_k Im(r_k),

elastic bending (``k_b``, N m/rad) and axial (``k_a``, N per unit strain)
energy about the straight, unstretched segment, and gravity (``g = 9.81``
m/s^2). With Rayleigh's dissipation ``1/2 qdot^T D qdot`` and the chamber
pressures ``P = (p1, ..., p_2n)`` (normalised, see below) the Euler-Lagrange
equations are::

    M(q) qddot + sum_k m_k Re(J_k^H a_k) + dV/dq + D qdot = B P,

with ``a_k = Jdot_k qdot`` the convective node acceleration (computed exactly
from the chord derivatives). The pressure difference of a segment's two
chambers bends it, their sum extends it (the classic pneumatic PCC actuation
model)::

    Q_theta_i = b_bend,i (p_{2i-1} - p_{2i}),    Q_eps_i = b_axial,i (p_{2i-1} + p_{2i}),

``b_bend`` in N m and ``b_axial`` in N per unit normalised pressure. Chamber
``p_{2i-1}`` sits on the image-left side of segment ``i``: inflating it
lengthens that side and bends the segment to the right (``theta_i`` grows).

Rest state and linearisation: the depressurised robot hangs straight
(``theta = 0``) and sags under its weight (``eps_i > 0``); ``q_rest`` solves
``dV/dq = 0``. About it ``M0 = M(q_rest)`` and ``K0 = d^2V/dq^2`` (central
differences of the exact gradient). Damping is Rayleigh's,
``D = alpha M0 + beta K0``, with ``alpha, beta`` chosen so that the two lowest
modes have the damping ratios ``zeta`` (Clough & Penzien, "Dynamics of
Structures", section 12-4): mode ``r`` then has
``zeta_r = alpha / (2 w_r) + beta w_r / 2``. The small-amplitude natural
frequencies ``f_r = |lambda_r| / 2 pi`` and damping ratios
``zeta_r = -Re(lambda_r) / |lambda_r|`` come from the eigenvalues
``lambda_r`` (upper half plane) of the quadratic problem
``(lambda^2 M0 + lambda D + K0) phi = 0``; a released robot rings at the
damped frequencies ``f_r sqrt(1 - zeta_r^2)``.

The motion is integrated by classical RK4 with ``n_substeps`` steps per frame
interval (default 4: ``h = dt / 4`` ~ 4.2 ms, so ``w h`` = 0.04 on the
lowest default mode and 0.47 on the fastest, 17.8 Hz, where RK4's numerical
damping adds ~1e-4 per step to a mode that is damped at ``zeta`` = 0.07
anyway), the pressure being evaluated exactly at every stage time, and
sampled at the frame times ``t_i = i dt``; the integrator is compiled with
numba (cached on disk). With ``D = 0`` and ``P = 0`` the energy ``T + V`` is
conserved to the integrator's error (a test).

Default parameters (:meth:`ContinuumRobot.default`): identical segments
``L0 = 0.14`` m, ``m = 0.05`` kg, ``k_b = 0.0762`` N m/rad, ``k_a = 3`` N,
``b_bend = 0.13`` N m, ``b_axial = 0.33`` N, a 20 g connector (two segments)
and a 10 g end cap, ``zeta = (0.03, 0.03)``. They are chosen so that the
lowest natural frequencies are close to the real robots' free oscillations
(paper Section 4.4: 4.63 Hz on one segment, 1.566 Hz on two): 4.631 Hz and
1.547 Hz here. The modes, ascending: one segment, bending 4.63 Hz and
extension 12.03 Hz; two segments, first bending 1.55 Hz, first extension
5.90 Hz, second bending 9.38 Hz, second extension 17.75 Hz.

Pressures
---------
Each chamber is driven independently by ``p_c(t) = g(t) p_max (1 + s_c(t) /
max|s_c|) / 2``, where ``s_c`` is a sum of ``n_components`` sinusoids with
frequencies drawn uniformly in the band ``[0.04, 2]`` Hz (Krauss et al.'s
input band), random phases and Rayleigh-distributed amplitudes scaled by
``f^-spectral_slope`` (smooth, mostly slow); the affine map keeps ``p_c`` in
``[0, p_max]`` (``max|s_c|`` is taken on a fine grid and padded by 1 %;
``p_max = 0.9``; the real normalised pressures lie in about
[0, 0.94]) and adds no frequency outside the band besides the mean. The gate
``g(t)`` in [0, 1] shapes the clip:

* head: ``g = 0`` for ``head_s`` seconds (the robot hangs at rest, exactly
  ``q_rest``), then a raised-cosine ramp to 1 over ``ramp_s``;
* ``n_rest`` depressurisation intervals inside the first ``train_fraction``
  of the clip (the consumer's contiguous training split): a fast
  raised-cosine release over ``release_s``, ``rest_s`` seconds at zero
  pressure (free oscillation, so the free frequency is identifiable from the
  training frames), then a ramp back over ``ramp_s``;
* tail: a final fast release, then zero pressure for the last ``tail_s``
  seconds (inside the held-out last ``1 - train_fraction``).

A release takes ``release_s = 0.05`` s, much shorter than the periods of the
bending modes, so the robot is let go from its deflected shape and rings
freely, like the real robot's final depressurisation event.

Picture
-------
A camera view of the hanging arm, as in the real recordings (a light robot
against a dark background): a dark, faintly textured background
(:func:`~lagsplat.synth._render.background`, darkened), a grey mount at the
top centre, and the PCC backbone drawn as a thick, tapering band, segment 1
off-white, segment 2 pale blue, a dark connector ring between them and a
rounded tip. The rest length fills ``0.74 H`` (one segment) or ``0.64 H``
(two, which curl further sideways) below the mount at ``0.08 H``. Shapes are drawn at ``supersample`` x resolution and area-reduced
(anti-aliasing), see :mod:`lagsplat.synth._render`.

Command line::

    python -m lagsplat.synth.continuum_robot --segments 2 --out results/robot_2seg.npz [--duration-s 150] [--seed 0]
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import os
import sys
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numba import njit
from scipy.linalg import eig, eigh
from scipy.optimize import root

from lagsplat.io.atomic import atomic_write
from lagsplat.synth._render import (
    SUPERSAMPLE,
    Canvas,
    background,
    check_supersample,
    over,
    parse_size,
    render_frames,
)

__all__ = [
    "DEFAULT_DURATION_S",
    "DT",
    "FPS",
    "PRESSURE_BAND_HZ",
    "ContinuumRobot",
    "ModalAnalysis",
    "PressureSchedule",
    "main",
    "pressure_keys",
    "render_continuum_robot",
    "simulate_continuum_robot",
    "write_robot_npz",
]

#: Frame interval of the Krauss recordings (s): 119.88 fps video, every 2nd frame.
DT = 1001.0 / 60000.0
#: Frame rate (Hz), exactly ``1 / DT`` (59.94006 fps).
FPS = 60000.0 / 1001.0
#: Band of the random chamber pressures (Hz), as driven by Krauss et al.
PRESSURE_BAND_HZ = (0.04, 2.0)
#: Default clip length (s): 8991 frames, a practical CPU benchmark.
DEFAULT_DURATION_S = 150.0
#: Gravity (m/s^2).
GRAVITY = 9.81

_SEGMENTS = (1, 2)

# Picture, in units of the frame height H (horizontal positions relative to W / 2).
_MOUNT_Y = 0.08  # robot base below the top edge
_REST_FILL = (0.74, 0.64)  # rest length of the whole robot, in H, for 1 and 2 segments (2: room to curl)
_HALF_WIDTH = (0.085, 0.062)  # body half-width at the mount and at the tip
_MOUNT_HALF_WIDTH = 0.16
_RING_LENGTH = 0.05  # connector ring, along the backbone
_RING_OVERHANG = 0.012  # ring radius beyond the body
_RENDER_NODES = 12  # backbone nodes per segment in the picture
_SEG_RGB = ((0.93, 0.92, 0.88), (0.70, 0.80, 0.93))
_RING_RGB = (0.12, 0.12, 0.14)
_MOUNT_RGB = (0.38, 0.38, 0.41)
_BG_GAIN = 0.2  # darkens the shared light background


# ------------------------------------------------------------------ kernels
@njit(cache=True, inline="always")
def _sinc3(x: float) -> tuple[float, float, float]:
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
def _kinematics(q, qd, L0, N):  # pragma: no cover - compiled; checked against numpy in the tests
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
        S, S1, S2 = _sinc3(x)
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
def _acceleration(q, qd, Pc, L0, N, mass, kdiag, D, B, g):  # pragma: no cover - compiled
    """``qddot`` from the Euler-Lagrange equations (module docstring)."""
    _, J, a = _kinematics(q, qd, L0, N)
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
def _integrate(y0, P_half, n_frames, n_sub, h, L0, N, mass, kdiag, D, B, g):  # pragma: no cover - compiled
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
                kv = _acceleration(qs, vs, P, L0, N, mass, kdiag, D, B, g)
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


# ------------------------------------------------------------------ checks
def _check_segments(n_segments: Any) -> int:
    """``n_segments`` as an int in {1, 2}; ValueError otherwise."""
    if isinstance(n_segments, bool) or not isinstance(n_segments, (int, np.integer)) or int(n_segments) not in _SEGMENTS:
        raise ValueError(f"n_segments must be 1 or 2 (the Krauss robots), got {n_segments!r}")
    return int(n_segments)


def _positive(value: Any, name: str, allow_zero: bool = False) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a number, got {value!r}") from exc
    if not math.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        raise ValueError(f"{name} must be {'non-negative' if allow_zero else 'positive'}, got {value!r}")
    return v


def _per_segment(value: Any, n: int, name: str, allow_zero: bool = False) -> tuple[float, ...]:
    """A scalar (for every segment) or ``n`` values, each finite and positive."""
    vals = [value] * n if np.ndim(value) == 0 else list(np.ravel(np.asarray(value, dtype=object)))
    if len(vals) != n:
        raise ValueError(f"{name} needs one value per segment ({n}), got {value!r}")
    return tuple(_positive(v, name, allow_zero) for v in vals)


def pressure_keys(n_segments: int) -> list[str]:
    """NPZ pressure keys of an ``n_segments`` robot: ``["p1", "p2"]`` or ``["p1", "p2", "p3", "p4"]``.

    Segment ``i`` owns ``p{2i-1}`` (image-left chamber) and ``p{2i}`` (image-right chamber).

    Raises:
        ValueError: if ``n_segments`` is not 1 or 2.
    """
    n = _check_segments(n_segments)
    return [f"p{c + 1}" for c in range(2 * n)]


# ------------------------------------------------------------------ model
@dataclass(frozen=True, eq=False)
class ModalAnalysis:
    """Linearisation of the depressurised robot about its rest state (module docstring).

    Attributes:
        q_rest: float64 ``[d]`` rest configuration ``(theta_1, eps_1, ...)``
            (theta 0, eps the gravity sag).
        mass: float64 ``[d, d]`` ``M0 = M(q_rest)`` (kg m^2, kg m, kg entries by coordinate).
        stiffness: float64 ``[d, d]`` ``K0``, Hessian of ``V`` at ``q_rest``.
        damping: float64 ``[d, d]`` Rayleigh damping ``D = alpha M0 + beta K0``.
        rayleigh: ``(alpha, beta)`` (1/s, s).
        f_natural_hz: float64 ``[d]`` small-amplitude natural frequencies ``|lambda| / 2 pi``, ascending.
        zeta: float64 ``[d]`` damping ratios ``-Re(lambda) / |lambda|`` of those modes.
        f_damped_hz: float64 ``[d]`` damped frequencies ``Im(lambda) / 2 pi``.
        mode_shapes: float64 ``[d, d]`` undamped mode shapes (columns,
            ``Phi^T M0 Phi = I``, largest entry positive); with Rayleigh
            damping they are also the damped modes.
    """

    q_rest: np.ndarray
    mass: np.ndarray
    stiffness: np.ndarray
    damping: np.ndarray
    rayleigh: tuple[float, float]
    f_natural_hz: np.ndarray
    zeta: np.ndarray
    f_damped_hz: np.ndarray
    mode_shapes: np.ndarray


@dataclass(frozen=True)
class ContinuumRobot:
    """A planar PCC soft arm of one or two pneumatic segments (physics in the module docstring).

    Per-segment tuples have one entry per segment, base first.

    Attributes:
        n_segments: 1 or 2.
        length_m: rest lengths ``L0_i`` (m).
        mass_kg: segment masses ``m_i`` (kg), spread along the arc.
        tip_mass_kg: point masses at each segment tip (kg): the connector ring, the end cap.
        k_bend: bending stiffness ``k_b,i`` (N m / rad of total bend angle).
        k_axial: axial stiffness ``k_a,i`` (N per unit strain).
        b_bend: bending torque per unit normalised pressure difference (N m).
        b_axial: extension force per unit normalised pressure sum (N).
        zeta: damping ratios of the two lowest modes (Rayleigh damping), each in (0, 1).
        n_nodes: sub-arcs ``N`` per segment in the lumped-mass model (>= 2).
        gravity: ``g`` (m/s^2, >= 0).
    """

    n_segments: int
    length_m: tuple[float, ...]
    mass_kg: tuple[float, ...]
    tip_mass_kg: tuple[float, ...]
    k_bend: tuple[float, ...]
    k_axial: tuple[float, ...]
    b_bend: tuple[float, ...]
    b_axial: tuple[float, ...]
    zeta: tuple[float, float] = (0.03, 0.03)
    n_nodes: int = 8
    gravity: float = GRAVITY

    def __post_init__(self) -> None:
        n = _check_segments(self.n_segments)
        for name in ("length_m", "mass_kg", "k_bend", "k_axial", "b_bend", "b_axial"):
            object.__setattr__(self, name, _per_segment(getattr(self, name), n, name))
        object.__setattr__(self, "tip_mass_kg", _per_segment(self.tip_mass_kg, n, "tip_mass_kg", allow_zero=True))
        z = _per_segment(self.zeta, 2, "zeta") if np.ndim(self.zeta) else (_positive(self.zeta, "zeta"),) * 2
        if not all(0.0 < v < 1.0 for v in z):
            raise ValueError(f"zeta must be in (0, 1) (under-damped), got {self.zeta!r}")
        object.__setattr__(self, "zeta", z)
        if isinstance(self.n_nodes, bool) or int(self.n_nodes) != self.n_nodes or int(self.n_nodes) < 2:
            raise ValueError(f"n_nodes must be an integer >= 2, got {self.n_nodes!r}")
        object.__setattr__(self, "n_nodes", int(self.n_nodes))
        object.__setattr__(self, "gravity", _positive(self.gravity, "gravity", allow_zero=True))

    @classmethod
    def default(cls, n_segments: int, **overrides: Any) -> ContinuumRobot:
        """The default robot (module docstring): identical 0.14 m segments, lowest mode 4.63 Hz (1) / 1.55 Hz (2).

        Args:
            n_segments: 1 or 2.
            **overrides: any field of :class:`ContinuumRobot` (scalars apply to every segment).

        Raises:
            ValueError: on a bad ``n_segments`` or an invalid / unknown override.
        """
        n = _check_segments(n_segments)
        known = {f for f in cls.__dataclass_fields__ if f != "n_segments"}
        unknown = sorted(set(overrides) - known)
        if unknown:
            raise ValueError(f"unknown robot parameter(s) {unknown}; known: {sorted(known)}")
        kw: dict[str, Any] = {
            "length_m": 0.14,
            "mass_kg": 0.05,
            "tip_mass_kg": (0.01,) if n == 1 else (0.02, 0.01),
            "k_bend": 0.0762,
            "k_axial": 3.0,
            "b_bend": 0.13,
            "b_axial": 0.33,
        }
        kw.update(overrides)
        return cls(n_segments=n, **kw)

    # -------------------------------------------------------------- arrays
    @property
    def d(self) -> int:
        """Number of generalised coordinates, ``2 n_segments``."""
        return 2 * self.n_segments

    @functools.cached_property
    def _arrays(self) -> dict[str, np.ndarray]:
        n, N = self.n_segments, self.n_nodes
        mass = np.zeros(n * N)
        for i in range(n):
            base = i * N
            mass[base:base + N] += self.mass_kg[i] / N
            mass[base + N - 1] -= self.mass_kg[i] / (2 * N)
            if i > 0:
                mass[base - 1] += self.mass_kg[i] / (2 * N)
            mass[base + N - 1] += self.tip_mass_kg[i]
        kdiag = np.ravel(np.column_stack([self.k_bend, self.k_axial])).astype(np.float64)
        B = np.zeros((self.d, self.d))
        for i in range(n):
            B[2 * i, 2 * i], B[2 * i, 2 * i + 1] = self.b_bend[i], -self.b_bend[i]
            B[2 * i + 1, 2 * i], B[2 * i + 1, 2 * i + 1] = self.b_axial[i], self.b_axial[i]
        return {"L0": np.asarray(self.length_m, np.float64), "mass": mass, "kdiag": kdiag, "B": B}

    @property
    def actuation_matrix(self) -> np.ndarray:
        """``B`` float64 ``[d, 2 n]``: generalised force ``Q = B P`` of the chamber pressures ``P``."""
        return self._arrays["B"].copy()

    def _q(self, q: Any, name: str = "q") -> np.ndarray:
        a = np.asarray(q, dtype=np.float64)
        if a.shape != (self.d,) or not np.all(np.isfinite(a)):
            raise ValueError(f"{name} must be {self.d} finite values (theta, eps per segment), got shape {a.shape}")
        return a

    # ------------------------------------------------------------- physics
    def kinematics(self, q: Any, qdot: Any | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Lumped-mass node positions, Jacobians and convective accelerations.

        Args:
            q: ``[d]`` configuration.
            qdot: ``[d]`` velocity (zeros if None).

        Returns:
            ``(r, J, a)``: complex ``[n N]`` node positions ``x + i y`` (m, y
            down, mount at 0), complex ``[n N, d]`` Jacobians ``dr/dq`` and
            complex ``[n N]`` convective accelerations ``Jdot qdot`` (m/s^2).

        Raises:
            ValueError: on a wrongly shaped or non-finite input.
        """
        qd = np.zeros(self.d) if qdot is None else self._q(qdot, "qdot")
        return _kinematics(self._q(q), qd, self._arrays["L0"], self.n_nodes)

    def mass_matrix(self, q: Any) -> np.ndarray:
        """``M(q)`` float64 ``[d, d]``, symmetric positive definite."""
        _, J, _ = self.kinematics(q)
        m = self._arrays["mass"]
        return (J.conj().T @ (J * m[:, None])).real

    def potential(self, q: Any) -> float:
        """``V(q)`` (J): elastic plus gravitational energy (zero at the straight, unstretched mount-level reference)."""
        qa = self._q(q)
        r, _, _ = self.kinematics(qa)
        return float(0.5 * np.sum(self._arrays["kdiag"] * qa * qa) - self.gravity * self._arrays["mass"] @ r.imag)

    def grad_potential(self, q: Any) -> np.ndarray:
        """``dV/dq`` float64 ``[d]`` (exact)."""
        qa = self._q(q)
        _, J, _ = self.kinematics(qa)
        return self._arrays["kdiag"] * qa - self.gravity * (self._arrays["mass"] @ J.imag)

    def kinetic_energy(self, q: Any, qdot: Any) -> float:
        """``T = 1/2 qdot^T M(q) qdot`` (J)."""
        v = self._q(qdot, "qdot")
        return float(0.5 * v @ self.mass_matrix(q) @ v)

    def acceleration(self, q: Any, qdot: Any, pressures: Any, damping: bool = True) -> np.ndarray:
        """``qddot`` float64 ``[d]`` from the Euler-Lagrange equations at pressures ``[2 n]``.

        ``damping=False`` drops ``D qdot`` (conservative check).
        """
        P = np.asarray(pressures, dtype=np.float64)
        if P.shape != (2 * self.n_segments,):
            raise ValueError(f"pressures must hold {2 * self.n_segments} values, got shape {P.shape}")
        ar = self._arrays
        D = self.modal.damping if damping else np.zeros((self.d, self.d))
        return _acceleration(self._q(q), self._q(qdot, "qdot"), P, ar["L0"], self.n_nodes, ar["mass"], ar["kdiag"], D, ar["B"], self.gravity)

    def rest_state(self) -> np.ndarray:
        """``q_rest`` float64 ``[d]``: the depressurised equilibrium ``dV/dq = 0`` (straight, sagging).

        Raises:
            ValueError: if the root finder does not converge.
        """
        sol = root(self.grad_potential, np.zeros(self.d), method="hybr", tol=1e-14)
        if not sol.success or np.max(np.abs(self.grad_potential(sol.x))) > 1e-10:
            raise ValueError(f"no rest state found for {self}: {sol.message}")
        q = sol.x.copy()
        q[0::2] = 0.0  # straight by symmetry (removes rounding)
        return q

    @functools.cached_property
    def modal(self) -> ModalAnalysis:
        """The :class:`ModalAnalysis` of the depressurised robot (cached).

        Raises:
            ValueError: if a mode is over-damped (no oscillation) or the
                Rayleigh coefficients come out negative.
        """
        q0 = self.rest_state()
        M0 = self.mass_matrix(q0)
        step = 1e-6
        K0 = np.empty((self.d, self.d))
        for c in range(self.d):
            e = np.zeros(self.d)
            e[c] = step
            K0[:, c] = (self.grad_potential(q0 + e) - self.grad_potential(q0 - e)) / (2 * step)
        K0 = 0.5 * (K0 + K0.T)
        w2, Phi = eigh(K0, M0)
        if np.any(w2 <= 0):
            raise ValueError(f"the rest state is not stable (K0 eigenvalues {w2})")
        w = np.sqrt(w2)
        (z1, z2), (w1, w2_) = self.zeta, (w[0], w[1])
        # zeta_r = alpha / (2 w_r) + beta w_r / 2 at the two lowest modes.
        alpha, beta = np.linalg.solve(np.array([[0.5 / w1, 0.5 * w1], [0.5 / w2_, 0.5 * w2_]]), np.array([z1, z2]))
        if alpha < 0 or beta < 0:
            raise ValueError(f"zeta = {self.zeta} gives negative Rayleigh coefficients alpha={alpha:.3g}, beta={beta:.3g}")
        D = alpha * M0 + beta * K0
        A = np.block([[np.zeros((self.d, self.d)), np.eye(self.d)], [-np.linalg.solve(M0, K0), -np.linalg.solve(M0, D)]])
        lam = eig(A, right=False)
        if np.sum(lam.imag > 0) != self.d:
            raise ValueError(f"a mode is over-damped (eigenvalues {np.sort_complex(lam)}); lower zeta")
        lam = lam[lam.imag > 0]
        lam = lam[np.argsort(np.abs(lam))]
        Phi = Phi * np.where(Phi[np.argmax(np.abs(Phi), axis=0), np.arange(self.d)] < 0, -1.0, 1.0)[None, :]
        return ModalAnalysis(
            q_rest=q0,
            mass=M0,
            stiffness=K0,
            damping=D,
            rayleigh=(float(alpha), float(beta)),
            f_natural_hz=np.abs(lam) / (2 * math.pi),
            zeta=-lam.real / np.abs(lam),
            f_damped_hz=lam.imag / (2 * math.pi),
            mode_shapes=Phi,
        )

    def backbone(self, q: Any, nodes_per_segment: int = _RENDER_NODES) -> tuple[np.ndarray, np.ndarray]:
        """Points on the PCC arcs and their tangent angles, for one or many configurations.

        Args:
            q: ``[d]`` or ``[T, d]`` configurations.
            nodes_per_segment: equal sub-arcs per segment (>= 1).

        Returns:
            ``(r, phi)``: complex ``[..., n K + 1]`` points ``x + i y`` (m, y
            down, the mount first, segment ends at multiples of ``K``) and
            float64 ``[..., n K + 1]`` tangent angles from the downward
            vertical (rad, positive towards +x).

        Raises:
            ValueError: on a wrong shape or non-finite values.
        """
        qa = np.asarray(q, dtype=np.float64)
        if qa.shape[-1:] != (self.d,) or qa.ndim not in (1, 2) or not np.all(np.isfinite(qa)):
            raise ValueError(f"q must be [d] or [T, d] finite configurations with d = {self.d}, got shape {qa.shape}")
        K = int(nodes_per_segment)
        if K < 1:
            raise ValueError(f"nodes_per_segment must be >= 1, got {nodes_per_segment!r}")
        th, ep = qa[..., 0::2], qa[..., 1::2]
        Phi = np.concatenate([np.zeros_like(th[..., :1]), np.cumsum(th, axis=-1)], axis=-1)  # base angles
        frac = (np.arange(K) + 0.5) / K
        phis = Phi[..., :-1, None] + th[..., :, None] * frac  # [..., n, K] chord angles
        ell = (np.asarray(self.length_m) / K) * (1.0 + ep) * np.sinc(th / (2 * K) / math.pi)
        chords = (ell[..., :, None] * 1j) * np.exp(-1j * phis)
        chords = chords.reshape(*chords.shape[:-2], -1)
        r = np.concatenate([np.zeros_like(chords[..., :1]), np.cumsum(chords, axis=-1)], axis=-1)
        node_phi = Phi[..., :-1, None] + th[..., :, None] * (np.arange(K) / K)
        node_phi = np.concatenate([node_phi.reshape(*node_phi.shape[:-2], -1), Phi[..., -1:]], axis=-1)
        return r, node_phi

    def params(self) -> dict[str, Any]:
        """The robot's parameters as JSON-serialisable values."""
        out = asdict(self)
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in out.items()}


# ------------------------------------------------------------------ pressures
def _raised_cosine(x: np.ndarray) -> np.ndarray:
    """0 for x <= 0, 1 for x >= 1, ``(1 - cos(pi x)) / 2`` between (C1-smooth step)."""
    xc = np.clip(x, 0.0, 1.0)
    return 0.5 * (1.0 - np.cos(math.pi * xc))


@dataclass(frozen=True)
class PressureSchedule:
    """Chamber pressures ``p_c(t) = g(t) p_max (1 + s_c(t) / max|s_c|) / 2`` (module docstring).

    Build it with :meth:`random`. All times in seconds.

    Attributes:
        n_chambers: ``2 n_segments``.
        duration_s: clip length.
        freqs_hz, phases, amplitudes: float64 ``[n_chambers, n_components]``
            of the sinusoids of ``s_c``.
        scale: float64 ``[n_chambers]``, ``max|s_c|`` over the clip.
        p_max: largest pressure (normalised by 101 325 Pa).
        head_s: end of the static head (start of the first ramp).
        ramp_s, release_s: durations of the ramps up and of the releases.
        rests: ``(t_release_start, t_ramp_start)`` of each mid-clip zero-pressure interval.
        tail_release_s: start of the final release; ``g = 0`` from ``tail_release_s + release_s`` on.
        params: the arguments of :meth:`random`.
    """

    n_chambers: int
    duration_s: float
    freqs_hz: np.ndarray
    phases: np.ndarray
    amplitudes: np.ndarray
    scale: np.ndarray
    p_max: float
    head_s: float
    ramp_s: float
    release_s: float
    rests: tuple[tuple[float, float], ...]
    tail_release_s: float
    params: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def random(
        cls,
        n_segments: int,
        duration_s: float = DEFAULT_DURATION_S,
        seed: int = 0,
        *,
        p_max: float = 0.9,
        band_hz: Sequence[float] = PRESSURE_BAND_HZ,
        n_components: int = 48,
        spectral_slope: float = 0.5,
        head_s: float | None = None,
        tail_s: float | None = None,
        rest_s: float | None = None,
        n_rest: int = 2,
        ramp_s: float = 2.0,
        release_s: float = 0.05,
        train_fraction: float = 0.8,
    ) -> PressureSchedule:
        """A seeded random schedule: static head, band-limited drive with rest intervals, depressurised tail.

        Args:
            n_segments: 1 or 2 (two chambers per segment).
            duration_s: clip length (s).
            seed: seeds every random draw (``np.random.default_rng(seed)``).
            p_max: largest pressure, normalised by 101 325 Pa (0 < p_max <= 2).
            band_hz: ``(f_lo, f_hi)`` band of the sinusoids (Hz), ``0 < f_lo < f_hi``.
            n_components: sinusoids per chamber (>= 1).
            spectral_slope: amplitudes scale as ``f^-spectral_slope`` (>= 0; 0 = flat).
            head_s: static head (s); default ``min(8, 0.06 duration_s)``.
            tail_s: depressurised tail (s); default ``min(20, 0.15 duration_s)``.
            rest_s: length of each mid-clip zero-pressure interval (s);
                default ``min(8, 0.06 duration_s)``.
            n_rest: number of such intervals, all inside the first
                ``train_fraction`` of the clip (>= 0).
            ramp_s: raised-cosine ramp from 0 to full drive (s).
            release_s: raised-cosine depressurisation (s), short so the robot rings.
            train_fraction: the consumer's contiguous training share (the
                tail must lie after it, the rests before it), in (0, 1).

        Returns:
            The :class:`PressureSchedule`.

        Raises:
            ValueError: on invalid arguments, or if the head, rests and tail do
                not fit (the tail must start after ``train_fraction *
                duration_s`` and at least one ramp of drive must remain
                between consecutive events); the message says which.
        """
        n_ch = 2 * _check_segments(n_segments)
        dur = _positive(duration_s, "duration_s")
        pm = _positive(p_max, "p_max")
        if pm > 2.0:
            raise ValueError(f"p_max is a pressure divided by 101325 Pa and must be <= 2, got {p_max!r}")
        try:
            f_lo, f_hi = (float(v) for v in band_hz)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"band_hz must be (f_lo, f_hi), got {band_hz!r}") from exc
        if not (0.0 < f_lo < f_hi and math.isfinite(f_hi)):
            raise ValueError(f"band_hz must satisfy 0 < f_lo < f_hi, got {band_hz!r}")
        if isinstance(n_components, bool) or int(n_components) != n_components or int(n_components) < 1:
            raise ValueError(f"n_components must be an integer >= 1, got {n_components!r}")
        slope = _positive(spectral_slope, "spectral_slope", allow_zero=True)
        if isinstance(n_rest, bool) or int(n_rest) != n_rest or int(n_rest) < 0:
            raise ValueError(f"n_rest must be an integer >= 0, got {n_rest!r}")
        tf = float(train_fraction)
        if not (0.0 < tf < 1.0):
            raise ValueError(f"train_fraction must be in (0, 1), got {train_fraction!r}")
        head = min(8.0, 0.06 * dur) if head_s is None else _positive(head_s, "head_s", allow_zero=True)
        tail = min(20.0, 0.15 * dur) if tail_s is None else _positive(tail_s, "tail_s")
        rest = min(8.0, 0.06 * dur) if rest_s is None else _positive(rest_s, "rest_s")
        ramp = _positive(ramp_s, "ramp_s")
        rel = _positive(release_s, "release_s")

        tail_release = dur - tail - rel
        if tail_release < tf * dur - 1e-9:
            raise ValueError(
                f"the depressurised tail ({tail:g} s + {rel:g} s release) must start after the training share "
                f"({tf:g} x {dur:g} s = {tf * dur:g} s); shorten tail_s or lengthen duration_s"
            )
        drive0 = head + ramp  # full drive from here
        if tail_release < drive0 + ramp:
            raise ValueError(
                f"duration_s = {dur:g} s leaves no drive between the head ({head:g} s + {ramp:g} s ramp) and the tail "
                f"({tail:g} s); lengthen duration_s or shorten head_s / tail_s"
            )
        rng = np.random.default_rng(int(seed))
        rests: list[tuple[float, float]] = []
        n_r = int(n_rest)
        if n_r:
            block = rel + rest + ramp  # release, zero, ramp back
            lo, hi = drive0 + ramp, tf * dur  # a ramp of drive before each rest and after it, all in training
            slot = (hi - lo) / n_r
            if slot < block + ramp:
                raise ValueError(
                    f"{n_r} rest interval(s) of {rest:g} s do not fit in the training share after the head "
                    f"({lo:g}..{tf * dur:g} s); use fewer (n_rest), shorter (rest_s) or a longer duration_s"
                )
            for k in range(n_r):
                # Anywhere in the slot that leaves a ramp of drive before the next one.
                start = lo + k * slot + rng.uniform(0.0, slot - block - ramp)
                rests.append((start, start + rel + rest))

        freqs = rng.uniform(f_lo, f_hi, (n_ch, int(n_components)))
        phases = rng.uniform(0.0, 2.0 * math.pi, (n_ch, int(n_components)))
        amps = rng.rayleigh(1.0, (n_ch, int(n_components))) * (freqs / f_lo) ** (-slope)
        sched = cls(
            n_chambers=n_ch,
            duration_s=dur,
            freqs_hz=freqs,
            phases=phases,
            amplitudes=amps,
            scale=np.ones(n_ch),
            p_max=pm,
            head_s=head,
            ramp_s=ramp,
            release_s=rel,
            rests=tuple(rests),
            tail_release_s=tail_release,
            params={
                "p_max": pm,
                "band_hz": [f_lo, f_hi],
                "n_components": int(n_components),
                "spectral_slope": slope,
                "head_s": head,
                "tail_s": tail,
                "rest_s": rest,
                "n_rest": n_r,
                "ramp_s": ramp,
                "release_s": rel,
                "train_fraction": tf,
            },
        )
        # max|s_c| on a grid fine enough for the band (>= 40 samples per shortest period).
        t_fine = np.linspace(0.0, dur, math.ceil(dur * f_hi * 40) + 2)
        scale = np.max(np.abs(sched.carrier(t_fine)), axis=0) * 1.01  # margin: the grid can miss the true peak
        object.__setattr__(sched, "scale", scale)
        return sched

    def carrier(self, t: Any) -> np.ndarray:
        """``s_c(t)`` float64 ``[len(t), n_chambers]`` (before normalisation), sum of in-band sinusoids."""
        tt = np.atleast_1d(np.asarray(t, dtype=np.float64))
        out = np.empty((tt.shape[0], self.n_chambers))
        for c in range(self.n_chambers):
            for a in range(0, tt.shape[0], 4096):
                arg = 2.0 * math.pi * tt[a:a + 4096, None] * self.freqs_hz[c] + self.phases[c]
                out[a:a + 4096, c] = np.cos(arg) @ self.amplitudes[c]
        return out

    def gate(self, t: Any) -> np.ndarray:
        """``g(t)`` float64 ``[len(t)]`` in [0, 1]: head, ramps, releases, rests, tail."""
        tt = np.atleast_1d(np.asarray(t, dtype=np.float64))
        g = _raised_cosine((tt - self.head_s) / self.ramp_s)
        for t_rel, t_up in self.rests:
            g = g * (1.0 - _raised_cosine((tt - t_rel) / self.release_s) + _raised_cosine((tt - t_up) / self.ramp_s))
        g = g * (1.0 - _raised_cosine((tt - self.tail_release_s) / self.release_s))
        return np.clip(g, 0.0, 1.0)

    def __call__(self, t: Any) -> np.ndarray:
        """Pressures float64 ``[len(t), n_chambers]`` in ``[0, p_max]`` at times ``t`` (s)."""
        tt = np.atleast_1d(np.asarray(t, dtype=np.float64))
        p = 0.5 * self.p_max * (1.0 + self.carrier(tt) / self.scale)
        p = p * self.gate(tt)[:, None]
        return np.clip(p, 0.0, self.p_max)

    @property
    def tail_start_s(self) -> float:
        """First time with zero pressure for good (end of the final release)."""
        return self.tail_release_s + self.release_s


# ------------------------------------------------------------------ simulation
def _n_frames(duration_s: float, fps: float = FPS) -> int:
    n = round(duration_s * fps)
    if n < 16:
        raise ValueError(f"duration_s = {duration_s!r} gives {n} frames; need at least 16")
    return n


def _simulate(robot: ContinuumRobot, schedule: Any, n_frames: int, n_substeps: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Integrate from ``q_rest`` at rest; returns ``(states [T, 2d], pressures [T, 2n])`` at ``t_i = i DT``.

    ``schedule`` is a :class:`PressureSchedule` or any callable mapping times
    ``[m]`` (s) to pressures ``[m, 2n]``; it is evaluated at every RK4 stage time.
    """
    if isinstance(n_substeps, bool) or int(n_substeps) != n_substeps or int(n_substeps) < 1:
        raise ValueError(f"n_substeps must be an integer >= 1, got {n_substeps!r}")
    n_sub = int(n_substeps)
    h = DT / n_sub
    t_half = np.arange(2 * n_sub * (n_frames - 1) + 1) * (0.5 * h)
    P_half = np.ascontiguousarray(schedule(t_half), dtype=np.float64)
    if P_half.shape != (t_half.shape[0], 2 * robot.n_segments) or not np.all(np.isfinite(P_half)):
        raise ValueError(f"the pressure schedule must give finite [m, {2 * robot.n_segments}] pressures, got shape {P_half.shape}")
    modal = robot.modal
    ar = robot._arrays
    y0 = np.concatenate([modal.q_rest, np.zeros(robot.d)])
    Y = _integrate(y0, P_half, n_frames, n_sub, h, ar["L0"], robot.n_nodes, ar["mass"], ar["kdiag"], modal.damping, ar["B"], robot.gravity)
    if not np.all(np.isfinite(Y)):
        raise ValueError("the continuum-robot integration diverged (non-finite state); lower p_max or the actuation gains")
    return Y, P_half[:: 2 * n_sub].copy()


def simulate_continuum_robot(
    n_segments: int,
    duration_s: float = DEFAULT_DURATION_S,
    seed: int = 0,
    *,
    robot: ContinuumRobot | None = None,
    n_substeps: int = 4,
    **schedule_kwargs: Any,
) -> tuple[np.ndarray, np.ndarray]:
    """Simulate the pressure-driven robot from rest, sampled at 59.94 fps.

    Args:
        n_segments: 1 or 2.
        duration_s: clip length (s); ``T = round(duration_s * FPS)`` frames.
        seed: seeds the pressure schedule (:meth:`PressureSchedule.random`).
        robot: the :class:`ContinuumRobot` (default :meth:`ContinuumRobot.default`);
            its ``n_segments`` must match.
        n_substeps: RK4 steps per frame interval (>= 1).
        **schedule_kwargs: keyword arguments of :meth:`PressureSchedule.random`
            (``p_max``, ``head_s``, ``tail_s``, ``rest_s``, ``n_rest``, ...).

    Returns:
        ``(states, pressures)``: float64 ``[T, 2d]`` states ``(q, qdot)``
        with ``q = (theta_1, eps_1[, theta_2, eps_2])`` (rad, strain) and
        ``qdot`` their rates (1/s), frame ``i`` at ``t_i = i * DT``; float64
        ``[T, 2 n]`` chamber pressures ``p1..p_2n`` (normalised by 101 325 Pa).

    Raises:
        ValueError: on invalid arguments (see :meth:`PressureSchedule.random`),
            a robot with another number of segments, or a diverging integration.
    """
    n = _check_segments(n_segments)
    rob = ContinuumRobot.default(n) if robot is None else robot
    if not isinstance(rob, ContinuumRobot) or rob.n_segments != n:
        raise ValueError(f"robot must be a ContinuumRobot with {n} segment(s), got {robot!r}")
    sched = PressureSchedule.random(n, duration_s, seed, **schedule_kwargs)
    return _simulate(rob, sched, _n_frames(sched.duration_s), n_substeps)


# ------------------------------------------------------------------ picture
def _layout(robot: ContinuumRobot, W: int, H: int) -> tuple[float, float, float]:
    """``(x0, y0, px_per_m)``: mount point in output pixels and the scale."""
    L_rest = float(np.sum(np.asarray(robot.length_m) * (1.0 + robot.modal.q_rest[1::2])))
    return W / 2.0, _MOUNT_Y * H, _REST_FILL[robot.n_segments - 1] * H / L_rest


def _backdrop(W: int, H: int, s: int, seed: int) -> np.ndarray:
    """Dark, faintly textured background with the mount, float64 ``[H, W, 3]``."""
    cv = Canvas(W, H, s)
    cv.rect(W / 2.0 - _MOUNT_HALF_WIDTH * H, 0.0, W / 2.0 + _MOUNT_HALF_WIDTH * H, _MOUNT_Y * H, _MOUNT_RGB)
    return np.clip(over(cv.reduce(W, H), _BG_GAIN * background(W, H, seed)), 0.0, 1.0)


def _fill(cv: Canvas, poly: np.ndarray, rgb: tuple[float, float, float]) -> None:
    """Fill a simple (possibly non-convex) polygon, complex vertices in output pixels, on ``cv``.

    Same placement convention as :meth:`Canvas.convex` (pixel centres at
    ``j + 0.5``, 4 fractional bits), vectorised for the many backbone vertices.
    """
    one = 1 << Canvas._SHIFT
    xy = np.stack([(poly.real * cv.s - 0.5) * one, (poly.imag * cv.s - 0.5) * one], axis=-1)
    cv2.fillPoly(cv.img, [np.round(xy).astype(np.int32)], (*rgb, 1.0), cv2.LINE_8, Canvas._SHIFT)


def _draw_robot(pts: np.ndarray, phi: np.ndarray, n: int, K: int, W: int, H: int, s: int) -> np.ndarray:
    """One frame of the arm from backbone pixels ``pts`` (complex ``[n K + 1]``) and angles; premultiplied RGBA."""
    cv = Canvas(W, H, s)
    nn = pts.shape[0]
    hw = H * (_HALF_WIDTH[0] + (_HALF_WIDTH[1] - _HALF_WIDTH[0]) * np.arange(nn) / (nn - 1))
    normal = np.cos(phi) - 1j * np.sin(phi)  # unit normal (image right when hanging)
    left, right = pts + hw * normal, pts - hw * normal
    for i in range(n):  # each segment's outline: one side down, the other back up
        sl = slice(i * K, (i + 1) * K + 1)
        _fill(cv, np.concatenate([left[sl], right[sl][::-1]]), _SEG_RGB[i])
    tip = pts[-1]
    cv.disc(tip.real, tip.imag, hw[-1], _SEG_RGB[n - 1])
    if n > 1:  # connector ring at the end of segment 1
        c, t = pts[K], 1j * np.exp(-1j * phi[K])  # centre, unit tangent
        half = 0.5 * _RING_LENGTH * H
        rw = hw[K] + _RING_OVERHANG * H
        ring = [c - half * t + rw * normal[K], c + half * t + rw * normal[K], c + half * t - rw * normal[K], c - half * t - rw * normal[K]]
        cv.convex([(z.real, z.imag) for z in ring], _RING_RGB)
    return cv.reduce(W, H)


def render_continuum_robot(
    q: Any,
    robot: ContinuumRobot,
    size: Sequence[int] = (32, 32),
    seed: int = 0,
    supersample: int = SUPERSAMPLE,
) -> np.ndarray:
    """Render the arm for a sequence of configurations (picture: module docstring).

    Args:
        q: ``[T, d]`` configurations ``(theta_1, eps_1[, theta_2, eps_2])``
            (the first ``d`` columns of :func:`simulate_continuum_robot`'s states).
        robot: the :class:`ContinuumRobot` that produced them (lengths, scale).
        size: output ``(W, H)`` pixels (each >= 16).
        seed: seed of the background's faint texture (nothing else).
        supersample: supersampling factor (>= 1).

    Returns:
        uint8 ``[T, H, W, 3]`` RGB frames.

    Raises:
        ValueError: if ``q`` is not a non-empty finite ``[T, d]`` array, or on
            a bad ``size`` / ``supersample``.
        TypeError: if ``robot`` is not a :class:`ContinuumRobot`.
    """
    if not isinstance(robot, ContinuumRobot):
        raise TypeError(f"robot must be a ContinuumRobot, got {type(robot).__name__}")
    qa = np.asarray(q, dtype=np.float64)
    if qa.ndim != 2 or qa.shape[1] != robot.d or qa.shape[0] < 1:
        raise ValueError(f"q must be a non-empty [T, {robot.d}] array of configurations, got shape {qa.shape}")
    W, H = parse_size(size, 16)
    s = check_supersample(supersample)
    r, phi = robot.backbone(qa, _RENDER_NODES)
    x0, y0, scale = _layout(robot, W, H)
    pts = complex(x0, y0) + scale * r
    n, K = robot.n_segments, _RENDER_NODES
    return render_frames(range(qa.shape[0]), lambda i: _draw_robot(pts[i], phi[i], n, K, W, H, s), _backdrop(W, H, s, seed))


# ------------------------------------------------------------------ file
def _jsonable(x: Any) -> Any:
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    return x


def write_robot_npz(
    path: str | os.PathLike[str],
    n_segments: int,
    duration_s: float = DEFAULT_DURATION_S,
    seed: int = 0,
    *,
    size: Sequence[int] = (32, 32),
    supersample: int = SUPERSAMPLE,
    n_substeps: int = 4,
    robot: dict[str, Any] | None = None,
    **schedule_kwargs: Any,
) -> dict[str, Any]:
    """Simulate, render and write the surrogate clip in the Krauss NPZ layout, with a sidecar JSON.

    The NPZ (``np.savez_compressed``) holds exactly ``images`` float32
    ``(T, 3, H, W)`` in [0, 1] (uint8 / 255, so multiples of 1/255) and one
    float32 ``(T,)`` array per chamber, ``p1, p2`` (one segment) or
    ``p1..p4`` (two), normalised by 101 325 Pa, like the real recordings. The
    metadata goes to ``<path>.json`` (e.g. ``robot_2seg.npz.json``)::

        n_segments, fps (60000/1001), dt (1001/60000 s), n_frames, duration_s,
        f_natural_hz   small-amplitude natural frequencies of the depressurised
                       robot (linearisation about q_rest), ascending
        zeta           their damping ratios; f_damped_hz  f sqrt(1 - zeta^2)
        head_frames    leading frames with all pressures zero (robot at rest)
        tail_start_frame  first frame of the depressurised tail (all later
                       pressures exactly zero)
        rest_frames    [[start, stop), ...] mid-clip zero-pressure intervals
        n_train_frames int(train_fraction T), the consumer's split
        pressure_keys, chambers, coordinates, q_rest, linearisation
        (mass, stiffness, damping, rayleigh, mode_shapes), seed, source,
        params: {robot, schedule, render, integration}

    Both files are written atomically (temporary file in the same folder,
    then ``os.replace``); on any failure neither is left behind in part.

    Args:
        path: output ``.npz`` path (parent folders are created).
        n_segments: 1 or 2.
        duration_s: clip length (s; default 150 s = 8991 frames).
        seed: seeds the pressures and the background texture.
        size: ``(W, H)`` pixels (default the Krauss 32 x 32).
        supersample: anti-aliasing factor of the renderer.
        n_substeps: RK4 steps per frame.
        robot: overrides of :meth:`ContinuumRobot.default` (e.g. ``{"zeta": 0.05}``).
        **schedule_kwargs: keyword arguments of :meth:`PressureSchedule.random`.

    Returns:
        The metadata dict written to the JSON.

    Raises:
        ValueError: on invalid arguments (naming the argument), or a path not ending in ``.npz``.
        TypeError: if ``robot`` is not a dict.
    """
    out = Path(path)
    if out.suffix != ".npz":
        raise ValueError(f"{out}: the output path must end in .npz")
    n = _check_segments(n_segments)
    if robot is not None and not isinstance(robot, dict):
        raise TypeError(f"robot must be a dict of ContinuumRobot.default overrides, got {type(robot).__name__}")
    rob = ContinuumRobot.default(n, **(robot or {}))
    W, H = parse_size(size, 16)
    s = check_supersample(supersample)
    sched = PressureSchedule.random(n, duration_s, seed, **schedule_kwargs)
    T = _n_frames(sched.duration_s)
    states, pressures = _simulate(rob, sched, T, n_substeps)
    frames = render_continuum_robot(states[:, : rob.d], rob, (W, H), seed, s)
    images = np.ascontiguousarray(np.moveaxis(frames, -1, 1).astype(np.float32) / np.float32(255.0))
    keys = pressure_keys(n)
    arrays: dict[str, np.ndarray] = {"images": images}
    for c, k in enumerate(keys):
        arrays[k] = pressures[:, c].astype(np.float32)

    zero = np.all(pressures == 0.0, axis=1)
    head_frames = int(np.argmin(zero)) if not zero.all() else T
    nonzero = np.flatnonzero(~zero)
    tail_start = int(nonzero[-1] + 1) if nonzero.size else 0
    t_frames = np.arange(T) * DT
    rest_frames = []
    for t_rel, t_up in sched.rests:
        inside = np.flatnonzero(zero & (t_frames >= t_rel) & (t_frames <= t_up))
        if inside.size:
            rest_frames.append([int(inside[0]), int(inside[-1] + 1)])
    modal = rob.modal
    meta: dict[str, Any] = {
        "source": "lagsplat.synth.continuum_robot",
        "npz": out.name,
        "n_segments": n,
        "fps": FPS,
        "dt": DT,
        "n_frames": T,
        "duration_s": T * DT,
        "f_natural_hz": modal.f_natural_hz,
        "zeta": modal.zeta,
        "f_damped_hz": modal.f_damped_hz,
        "tail_start_frame": tail_start,
        "head_frames": head_frames,
        "rest_frames": rest_frames,
        "n_train_frames": int(sched.params["train_fraction"] * T),
        "seed": int(seed),
        "pressure_keys": keys,
        "pressure_units": "gauge pressure / 101325 Pa",
        "chambers": {k: f"segment {c // 2 + 1}, {'image-left (bends it right, theta grows)' if c % 2 == 0 else 'image-right (bends it left)'}" for c, k in enumerate(keys)},
        "coordinates": [f"{name}_{i + 1}" for i in range(n) for name in ("theta", "eps")],
        "q_rest": modal.q_rest,
        "linearisation": {
            "mass": modal.mass,
            "stiffness": modal.stiffness,
            "damping": modal.damping,
            "rayleigh_alpha_beta": list(modal.rayleigh),
            "mode_shapes": modal.mode_shapes,
        },
        "params": {
            "robot": rob.params(),
            "schedule": sched.params,
            "render": {"size": [W, H], "supersample": s},
            "integration": {"method": "rk4", "n_substeps": int(n_substeps)},
        },
    }
    meta = _jsonable(meta)
    text = json.dumps(meta, indent=2) + "\n"
    json_path = out.with_name(out.name + ".json")
    with atomic_write(out) as tmp_npz, atomic_write(json_path) as tmp_json:
        with open(tmp_npz, "wb") as fh:  # a file object: numpy must not append ".npz"
            np.savez_compressed(fh, **arrays)
        tmp_json.write_text(text)
        for tmp in (tmp_npz, tmp_json):  # mkstemp makes 0600 files; data files are world-readable
            os.chmod(tmp, 0o644)
    return meta


# ------------------------------------------------------------------ CLI
class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, exit status 2
        self.exit(2, f"{self.prog}: error: {message}\n")


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m lagsplat.synth.continuum_robot --segments {1,2} --out PATH.npz [--duration-s S] [--seed N]``.

    Prints the written path. Returns 0; bad arguments exit with status 2 and
    a one-line message on stderr.
    """
    p = _Parser(prog="python -m lagsplat.synth.continuum_robot", description="Write the offline soft-robot surrogate clip (Krauss NPZ layout).")
    p.add_argument("--segments", type=int, choices=_SEGMENTS, required=True, help="number of segments (1 or 2)")
    p.add_argument("--out", required=True, help="output .npz path (metadata goes to <out>.json)")
    p.add_argument("--duration-s", type=float, default=DEFAULT_DURATION_S, help=f"clip length in seconds (default {DEFAULT_DURATION_S:g})")
    p.add_argument("--seed", type=int, default=0, help="seed of the pressures and the background texture (default 0)")
    args = p.parse_args(argv)
    try:
        write_robot_npz(args.out, args.segments, args.duration_s, args.seed)
    except ValueError as exc:
        print(f"{p.prog}: error: {str(exc).splitlines()[0]}", file=sys.stderr)
        return 2
    print(args.out)
    return 0


if __name__ == "__main__":  # pragma: no cover - exercised through a subprocess in the tests
    sys.exit(main())
