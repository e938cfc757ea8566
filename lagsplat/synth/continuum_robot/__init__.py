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

from lagsplat.synth.continuum_robot.cli import main
from lagsplat.synth.continuum_robot.constants import (
    DEFAULT_DURATION_S,
    DT,
    FPS,
    GRAVITY,
    PRESSURE_BAND_HZ,
)
from lagsplat.synth.continuum_robot.model import (
    ContinuumRobot,
    ModalAnalysis,
    pressure_keys,
)
from lagsplat.synth.continuum_robot.pressure import PressureSchedule
from lagsplat.synth.continuum_robot.render import render_continuum_robot
from lagsplat.synth.continuum_robot.simulate import (
    n_frames_for,
    simulate_continuum_robot,
    simulate_frames,
)
from lagsplat.synth.continuum_robot.writer import write_robot_npz

__all__ = [
    "DEFAULT_DURATION_S",
    "DT",
    "FPS",
    "PRESSURE_BAND_HZ",
    "GRAVITY",
    "ContinuumRobot",
    "ModalAnalysis",
    "PressureSchedule",
    "main",
    "pressure_keys",
    "render_continuum_robot",
    "simulate_continuum_robot",
    "write_robot_npz",
    "simulate_frames",
    "n_frames_for",
]
