"""Two spring-coupled carts with exactly known modes, rendered as a small video clip.

The synthetic 2-DOF truth for the full latent Lagrangian with ``d = 2``
: a model's identified modal frequencies are checked against
``clip.meta["truth"]["f_modes_hz"]`` (within 3 %) and its damping ratios
against ``clip.meta["truth"]["zeta_modes"]`` (within 30 %).

Physics
-------
Two carts of masses ``m1, m2`` (kg) on frictionless horizontal rails, with
displacements ``x = (x1, x2)`` from rest; a wall spring ``k1`` holds cart 1,
a coupling spring ``k2`` joins the carts and a wall spring ``k3`` holds cart
2 (N/m)::

    M x'' + C x' + K x = 0,   M = diag(m1, m2),
                              K = [[k1 + k2, -k2], [-k2, k2 + k3]].

The mass-normalised mode shapes ``Phi`` (columns, ``Phi^T M Phi = I``,
``Phi^T K Phi = diag(w_i^2)``, ``w_1 < w_2``) come from the generalised
eigenproblem ``K phi = w^2 M phi``; the damping is modal (proportional)::

    C = M Phi diag(2 zeta_i w_i) Phi^T M,

so ``Phi^T C Phi = diag(2 zeta_i w_i)`` and mode ``i`` is an independent
damped oscillator with natural frequency ``f_i = w_i / 2 pi``, damping ratio
``zeta_i``, damped frequency ``f_i sqrt(1 - zeta_i^2)`` and amplitude envelope
``exp(-zeta_i w_i t)``. The motion is integrated exactly: the first-order
state ``y = (x, x')`` is propagated frame to frame with the matrix exponential
``expm(A / fps)`` of ``A = [[0, I], [-M^-1 K, -M^-1 C]]`` and sampled at
``t_i = i / fps``.

The system is specified either by its springs (:meth:`CoupledCarts.from_springs`)
or, as the clip generator does, by the two modal frequencies, the masses and
the wall-spring ratio ``k3 / k1`` (:meth:`CoupledCarts.from_modes`, which
solves for the springs in closed form). Displacements are in units of the
image width; as the system is linear, that choice changes no frequency or
damping ratio.

Picture
-------
Horizontal geometry is in units of the frame width ``W``, vertical geometry
in units of the frame height ``H``, so any frame size works. Cart 1 (red)
runs on a rail at ``y = 0.38 H`` (it occupies the upper half of the frame),
cart 2 (blue) on a rail at ``y = 0.86 H`` (lower half); at rest both are
centred at ``x = W / 2``, and a displacement ``x_j`` moves cart ``j`` by
``x_j W`` (positive to the right). Each cart is a ``0.18 W x 0.17 H``
rectangle with a dark outline on two dark wheels. The rails and the end walls
are static; the springs are not drawn (a deforming spring would be a second,
non-rigid moving object in the picture). As in :mod:`lagsplat.synth.pendulum`,
shapes are rendered at 4x the output resolution, reduced with
``cv2.INTER_AREA`` and composited over the same light, faintly textured
static background.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.linalg import eigh, expm

from lagsplat.io.clip import HELD_OUT, TRAIN, Clip, segments
from lagsplat.timeseries import spectral_peak_frequency
from lagsplat.synth._clip import check_timing, check_train_fraction, contiguous_train_frames
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
    "CoupledCarts",
    "simulate_coupled_carts",
    "render_coupled_carts",
    "make_coupled_carts_clip",
    "RAIL_Y",
    "CART_WIDTH",
    "CART_HEIGHT",
    "MAX_DISPLACEMENT",
]

#: Rail heights of cart 1 and cart 2, in units of the frame height.
RAIL_Y = (0.38, 0.86)
#: Cart body width (units of the frame width) and height (units of the frame height).
CART_WIDTH = 0.18
CART_HEIGHT = 0.17
#: Largest displacement |x_j| (units of the frame width) the renderer accepts:
#: the cart then still clears the end walls.
MAX_DISPLACEMENT = 0.35

_WALL_WIDTH = 0.035  # units of W
_WALL_HEIGHT = 0.27  # units of H, above the rail
_RAIL_THICKNESS = 0.025  # units of H, below the rail line
_BODY_LIFT = 0.06  # body bottom above the rail, units of H
_WHEEL_RADIUS = 0.045  # units of H
_WHEEL_OFFSET = 0.27  # wheel centres at +- this fraction of the cart width
_OUTLINE = 0.025  # units of H

# Colours, RGB in [0, 1].
_CART_RGB = ((0.86, 0.16, 0.12), (0.14, 0.30, 0.86))  # cart 1 red, cart 2 blue
_OUTLINE_RGB = (0.12, 0.12, 0.14)
_WHEEL_RGB = (0.20, 0.20, 0.22)
_RAIL_RGB = (0.35, 0.35, 0.37)
_WALL_RGB = (0.45, 0.42, 0.38)


# --------------------------------------------------------------------- physics
def _pair(value: Any, name: str) -> tuple[float, float]:
    """A scalar (used for both entries) or a length-2 sequence, as two finite floats."""
    if np.ndim(value) == 0:
        try:
            v = float(value)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{name} must be a number or a pair of numbers, got {value!r}") from exc
        out = (v, v)
    else:
        try:
            arr = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{name} must be a number or a pair of numbers, got {value!r}") from exc
        if arr.shape != (2,):
            raise ValueError(f"{name} must be a number or a pair of numbers, got {value!r}")
        out = (float(arr[0]), float(arr[1]))
    if not all(math.isfinite(v) for v in out):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return out


@dataclass(frozen=True, eq=False)
class CoupledCarts:
    """A linear two-cart system with modal damping, and its exact modal truth.

    Build it with :meth:`from_springs` or :meth:`from_modes`; the constructor
    takes the already-derived quantities.

    Attributes:
        masses: ``(m1, m2)`` in kg.
        springs: ``(k1, k2, k3)`` in N/m: wall-cart 1, cart 1-cart 2, cart 2-wall.
        zeta_modes: damping ratio of mode 1 and mode 2 (ascending frequency).
        mass: float64 ``[2, 2]`` mass matrix ``M``.
        stiffness: float64 ``[2, 2]`` stiffness matrix ``K``.
        damping: float64 ``[2, 2]`` damping matrix ``C = M Phi diag(2 zeta w) Phi^T M``.
        mode_shapes: float64 ``[2, 2]`` ``Phi``, column ``i`` = mode ``i``,
            mass-normalised (``Phi^T M Phi = I``), sign chosen so that the
            cart-1 component is positive.
        omega: float64 ``[2]`` undamped modal natural frequencies (rad/s), ascending.
    """

    masses: tuple[float, float]
    springs: tuple[float, float, float]
    zeta_modes: tuple[float, float]
    mass: np.ndarray
    stiffness: np.ndarray
    damping: np.ndarray
    mode_shapes: np.ndarray
    omega: np.ndarray

    # ---------------------------------------------------------- constructors
    @classmethod
    def from_springs(
        cls,
        masses: Sequence[float] = (1.0, 1.5),
        springs: Sequence[float] = (18.0, 14.0, 18.0),
        zeta: float | Sequence[float] = 0.02,
    ) -> CoupledCarts:
        """The system with the given masses and spring constants.

        Args:
            masses: ``(m1, m2)`` in kg, each > 0.
            springs: ``(k1, k2, k3)`` in N/m: ``k2 > 0`` (the carts are coupled),
                ``k1, k3 >= 0`` with ``k1 + k3 > 0`` (no free rigid-body mode).
            zeta: damping ratio of both modes, or ``(zeta_1, zeta_2)`` by
                ascending frequency; each in ``[0, 1)`` (under-damped).

        Returns:
            The :class:`CoupledCarts`.

        Raises:
            ValueError: on a non-positive mass, an invalid spring set or a
                damping ratio outside ``[0, 1)``.
        """
        m1, m2 = _pair(masses, "masses")
        if not (m1 > 0 and m2 > 0):
            raise ValueError(f"masses must be positive, got {masses!r}")
        try:
            k = np.asarray(springs, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"springs must be (k1, k2, k3), got {springs!r}") from exc
        if k.shape != (3,) or not np.all(np.isfinite(k)):
            raise ValueError(f"springs must be three finite numbers (k1, k2, k3), got {springs!r}")
        k1, k2, k3 = (float(v) for v in k)
        if not (k2 > 0 and k1 >= 0 and k3 >= 0 and k1 + k3 > 0):
            raise ValueError(
                f"springs (k1, k2, k3) = {springs!r} need k2 > 0 (coupled carts) and k1, k3 >= 0 with "
                "k1 + k3 > 0 (anchored to a wall)"
            )
        z = _pair(zeta, "zeta")
        if not all(0.0 <= v < 1.0 for v in z):
            raise ValueError(f"zeta must be in [0, 1) (under-damped) for each mode, got {zeta!r}")

        M = np.diag([m1, m2])
        K = np.array([[k1 + k2, -k2], [-k2, k2 + k3]])
        w2, Phi = eigh(K, M)  # ascending, Phi^T M Phi = I
        Phi = Phi * np.where(Phi[0] < 0, -1.0, 1.0)[None, :]
        omega = np.sqrt(w2)
        C = M @ Phi @ np.diag(2.0 * np.asarray(z) * omega) @ Phi.T @ M
        C = 0.5 * (C + C.T)
        return cls((m1, m2), (k1, k2, k3), z, M, K, C, Phi, omega)

    @classmethod
    def from_modes(
        cls,
        f_modes_hz: Sequence[float] = (0.6, 1.0),
        zeta: float | Sequence[float] = 0.02,
        masses: Sequence[float] = (1.0, 1.5),
        wall_ratio: float = 1.0,
    ) -> CoupledCarts:
        """The system with prescribed undamped modal frequencies.

        Solves for ``k1, k2 > 0`` with ``k3 = wall_ratio * k1`` such that the
        eigenvalues of ``M^-1 K`` are ``(2 pi f_1)^2, (2 pi f_2)^2``: matching
        the trace and the determinant gives a quadratic in ``k1``. Where both
        roots are physical, the one with the weaker coupling spring ``k2`` is
        taken. ``wall_ratio = m2 / m1`` is always feasible (then mode 1 is the
        carts moving together); other ratios give less symmetric mode shapes
        but are infeasible for some frequency pairs.

        Args:
            f_modes_hz: ``(f_1, f_2)`` undamped modal natural frequencies (Hz),
                ``0 < f_1 < f_2``.
            zeta: damping ratio of both modes or ``(zeta_1, zeta_2)``, in ``[0, 1)``.
            masses: ``(m1, m2)`` in kg, each > 0.
            wall_ratio: ``k3 / k1`` (> 0).

        Returns:
            The :class:`CoupledCarts`; its frequencies equal ``f_modes_hz`` to
            rounding (relative error < 1e-9, checked).

        Raises:
            ValueError: on invalid arguments, or if no positive springs with
                that wall ratio give these frequencies (the message suggests
                ``wall_ratio = m2 / m1``).
        """
        f1, f2 = _pair(f_modes_hz, "f_modes_hz")
        if not (0.0 < f1 < f2):
            raise ValueError(f"f_modes_hz must be two distinct positive frequencies in ascending order, got {f_modes_hz!r}")
        m1, m2 = _pair(masses, "masses")
        if not (m1 > 0 and m2 > 0):
            raise ValueError(f"masses must be positive, got {masses!r}")
        r = float(wall_ratio)
        if not (math.isfinite(r) and r > 0):
            raise ValueError(f"wall_ratio (k3 / k1) must be positive, got {wall_ratio!r}")

        lam1, lam2 = (2.0 * math.pi * f1) ** 2, (2.0 * math.pi * f2) ** 2
        S, P = lam1 + lam2, lam1 * lam2
        a = 1.0 / m1 + r / m2  # trace:       a k1 + b k2 = S
        b = 1.0 / m1 + 1.0 / m2  # determinant: r k1^2 + (1 + r) k1 k2 = P m1 m2
        qa, qb, qc = r - (1.0 + r) * a / b, (1.0 + r) * S / b, -P * m1 * m2
        if abs(qa) <= 1e-12 * (abs(r) + (1.0 + r) * a / b):
            roots = [-qc / qb]
        else:
            disc = qb * qb - 4.0 * qa * qc
            if disc < 0:
                roots = []
            else:
                sq = math.sqrt(disc)
                q = -0.5 * (qb + math.copysign(sq, qb))  # numerically stable pair
                roots = [q / qa, qc / q] if q != 0 else [-qb / (2.0 * qa)]
        candidates = []
        for k1 in roots:
            k2 = (S - a * k1) / b
            if not (k1 > 0 and k2 > 0):
                continue
            sys_ = cls.from_springs((m1, m2), (k1, k2, r * k1), zeta)
            if np.allclose(sys_.f_modes_hz, (f1, f2), rtol=1e-9, atol=0.0):
                candidates.append(sys_)
        if not candidates:
            raise ValueError(
                f"no positive springs with k3 / k1 = wall_ratio = {r:g} give modes {(f1, f2)} Hz for masses "
                f"{(m1, m2)} kg; wall_ratio = m2 / m1 = {m2 / m1:g} always works"
            )
        return min(candidates, key=lambda s: s.springs[1])

    # ------------------------------------------------------------------ views
    @property
    def f_modes_hz(self) -> np.ndarray:
        """Undamped modal natural frequencies (Hz), float64 ``[2]``, ascending."""
        return self.omega / (2.0 * math.pi)

    @property
    def f_modes_damped_hz(self) -> np.ndarray:
        """Damped modal frequencies ``f_i sqrt(1 - zeta_i^2)`` (Hz), float64 ``[2]``."""
        return self.f_modes_hz * np.sqrt(1.0 - np.asarray(self.zeta_modes) ** 2)

    @property
    def decay_rates(self) -> np.ndarray:
        """Modal amplitude decay rates ``zeta_i w_i`` (1/s), float64 ``[2]``."""
        return np.asarray(self.zeta_modes) * self.omega

    def state_matrix(self) -> np.ndarray:
        """First-order system matrix ``A`` ``[4, 4]`` of ``y = (x1, x2, x1', x2')``, ``y' = A y``."""
        Minv = np.linalg.inv(self.mass)
        A = np.zeros((4, 4))
        A[:2, 2:] = np.eye(2)
        A[2:, :2] = -Minv @ self.stiffness
        A[2:, 2:] = -Minv @ self.damping
        return A

    def truth(self) -> dict[str, Any]:
        """The exact modal truth as JSON-serialisable lists (see :func:`make_coupled_carts_clip`)."""
        return {
            "f_modes_hz": [float(v) for v in self.f_modes_hz],
            "zeta_modes": [float(v) for v in self.zeta_modes],
            "f_modes_damped_hz": [float(v) for v in self.f_modes_damped_hz],
            "decay_rates_per_s": [float(v) for v in self.decay_rates],
            "mass": self.mass.tolist(),
            "stiffness": self.stiffness.tolist(),
            "damping": self.damping.tolist(),
            "mode_shapes": self.mode_shapes.tolist(),
            "springs": [float(v) for v in self.springs],
        }


def simulate_coupled_carts(
    system: CoupledCarts,
    x0: Sequence[float],
    v0: Sequence[float],
    fps: float,
    n_frames: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact free motion of the two carts, sampled at ``t_i = i / fps``.

    The state ``y = (x, x')`` is advanced frame to frame by the matrix
    exponential ``expm(A / fps)`` of the first-order system (no integration
    error; rounding only).

    Args:
        system: the :class:`CoupledCarts`.
        x0: initial displacements ``(x1, x2)`` (any length unit; the clip uses
            image widths).
        v0: initial velocities ``(x1', x2')`` (that unit per second).
        fps: sampling rate (frames per second, > 0).
        n_frames: number of samples ``T`` (integer >= 2).

    Returns:
        ``(x, v, t)``: float64 ``[T, 2]`` displacements, float64 ``[T, 2]``
        velocities and float64 ``[T]`` times in seconds.

    Raises:
        ValueError: on invalid arguments.
    """
    if not isinstance(system, CoupledCarts):
        raise ValueError(f"system must be a CoupledCarts, got {type(system).__name__}")
    x0_ = np.asarray(x0, dtype=np.float64)
    v0_ = np.asarray(v0, dtype=np.float64)
    if x0_.shape != (2,) or v0_.shape != (2,):
        raise ValueError(f"x0 and v0 must each hold 2 values (one per cart), got shapes {x0_.shape} and {v0_.shape}")
    if not (np.all(np.isfinite(x0_)) and np.all(np.isfinite(v0_))):
        raise ValueError("x0 and v0 must be finite")
    fps_f = float(fps)
    if not (math.isfinite(fps_f) and fps_f > 0):
        raise ValueError(f"fps must be positive, got {fps!r}")
    n = int(n_frames)
    if n < 2 or n != n_frames:
        raise ValueError(f"n_frames must be an integer >= 2, got {n_frames!r}")

    step = expm(system.state_matrix() / fps_f)
    y = np.empty((n, 4))
    y[0, :2], y[0, 2:] = x0_, v0_
    for i in range(1, n):
        y[i] = step @ y[i - 1]
    t = np.arange(n, dtype=np.float64) / fps_f
    return y[:, :2].copy(), y[:, 2:].copy(), t


# ------------------------------------------------------------------- picture
def _backdrop(W: int, H: int, s: int, seed: int) -> np.ndarray:
    """Background with the static rails and end walls, float64 ``[H, W, 3]`` in [0, 1]."""
    cv = Canvas(W, H, s)
    ww = _WALL_WIDTH * W
    for ry in RAIL_Y:
        y = ry * H
        cv.rect(ww, y, W - ww, y + _RAIL_THICKNESS * H, _RAIL_RGB)
        cv.rect(0.0, y - _WALL_HEIGHT * H, ww, y + _RAIL_THICKNESS * H, _WALL_RGB)
        cv.rect(W - ww, y - _WALL_HEIGHT * H, W, y + _RAIL_THICKNESS * H, _WALL_RGB)
    # Every painted pixel has coverage 1, so the colours are premultiplied.
    return np.clip(over(cv.reduce(W, H), background(W, H, seed)), 0.0, 1.0)


def _carts(x: np.ndarray, W: int, H: int, s: int) -> np.ndarray:
    """Both carts at displacements ``x`` ``[2]``: premultiplied RGBA ``[H, W, 4]``."""
    cv = Canvas(W, H, s)
    hw, bh, ol = 0.5 * CART_WIDTH * W, CART_HEIGHT * H, _OUTLINE * H
    for j, ry in enumerate(RAIL_Y):
        cx = (0.5 + float(x[j])) * W
        y = ry * H
        wr = _WHEEL_RADIUS * H
        for sgn in (-1.0, 1.0):
            cv.disc(cx + sgn * _WHEEL_OFFSET * 2.0 * hw, y - wr, wr, _WHEEL_RGB)
        top, bottom = y - _BODY_LIFT * H - bh, y - _BODY_LIFT * H
        cv.rect(cx - hw, top, cx + hw, bottom, _OUTLINE_RGB)
        cv.rect(cx - hw + ol, top + ol, cx + hw - ol, bottom - ol, _CART_RGB[j])
    return cv.reduce(W, H)


def render_coupled_carts(
    x: Sequence[Sequence[float]] | np.ndarray,
    size: Sequence[int] = (64, 64),
    seed: int = 0,
    supersample: int = SUPERSAMPLE,
) -> np.ndarray:
    """Render the two carts for a sequence of displacements.

    Args:
        x: ``[T, 2]`` displacements of cart 1 (red, upper rail) and cart 2
            (blue, lower rail) from the frame centre, in units of the frame
            width, positive to the right; ``|x| <= MAX_DISPLACEMENT`` (0.35).
        size: output ``(W, H)`` in pixels (each >= 16).
        seed: seed of the background's smooth noise (nothing else depends on it).
        supersample: supersampling factor (>= 1; 4 by default), reduced with
            ``cv2.INTER_AREA``.

    Returns:
        uint8 ``[T, H, W, 3]`` RGB frames.

    Raises:
        ValueError: if ``x`` is not a non-empty finite ``[T, 2]`` array, a
            displacement exceeds ``MAX_DISPLACEMENT`` (the cart would hit the
            end wall), or ``size`` / ``supersample`` is invalid.
    """
    xs = np.asarray(x, dtype=np.float64)
    if xs.ndim != 2 or xs.shape[1] != 2 or xs.shape[0] < 1:
        raise ValueError(f"x must be a non-empty [T, 2] array of cart displacements, got shape {xs.shape}")
    if not np.all(np.isfinite(xs)):
        raise ValueError("x contains NaN or inf")
    peak = float(np.max(np.abs(xs)))
    if peak > MAX_DISPLACEMENT * (1.0 + 1e-9):  # tolerate rounding of a scaled peak
        raise ValueError(
            f"displacement {peak:.3f} frame widths exceeds MAX_DISPLACEMENT = {MAX_DISPLACEMENT} "
            "(the cart would run into the end wall)"
        )
    W, H = parse_size(size, 16)
    s = check_supersample(supersample)
    return render_frames(xs, lambda xi: _carts(xi, W, H, s), _backdrop(W, H, s, seed))


# ---------------------------------------------------------------------- clip
def _episode_start(system: CoupledCarts, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Seeded initial state exciting both modes comparably (before amplitude scaling).

    Mode ``i`` gets the modal coordinate ``q_i(t) = a_i exp(-zeta_i w_i t)
    cos(w_di t - phi_i)`` with a uniform random phase ``phi_i`` and ``a_i`` such
    that the mode alone would move its more-moving cart by ``r_i``, ``r_i``
    uniform in ``[0.6, 1]``. Returns ``(x0, v0, a)``.
    """
    Phi = system.mode_shapes
    r = rng.uniform(0.6, 1.0, 2)
    phi = rng.uniform(0.0, 2.0 * math.pi, 2)
    a = r / np.max(np.abs(Phi), axis=0)
    zw = system.decay_rates
    wd = 2.0 * math.pi * system.f_modes_damped_hz
    q0 = a * np.cos(phi)
    dq0 = a * (-zw * np.cos(phi) + wd * np.sin(phi))
    return Phi @ q0, Phi @ dq0, a


def make_coupled_carts_clip(
    size: Sequence[int] = (64, 64),
    fps: float = 30.0,
    duration_s: float = 20.0,
    f_modes_hz: Sequence[float] = (0.6, 1.0),
    zeta: float | Sequence[float] = (0.02, 0.015),
    masses: Sequence[float] = (1.0, 1.5),
    wall_ratio: float = 1.0,
    amplitude: float = 0.25,
    n_episodes: int = 4,
    held_out_episodes: int = 1,
    train_fraction: float | None = None,
    seed: int = 0,
) -> Clip:
    """The synthetic coupled-carts clip (several recordings) with its exact modal truth.

    ``n_episodes`` recordings of one system (:meth:`CoupledCarts.from_modes`),
    each ``T_e = round(duration_s * fps)`` frames long and started from its own
    seeded state that excites both modes with comparable amplitude (random
    phases, modal amplitudes within a factor 0.6 of each other, see
    ``meta["episodes"]``), scaled so that the largest cart displacement of the
    episode is ``amplitude`` frame widths. The recordings are stored back to
    back: ``episode`` is the recording index and ``t_i = i / fps`` over the
    whole clip (the step between two episodes is one frame interval, though
    the state jumps; no window may cross an ``episode`` boundary).

    Split rule:

    * ``n_episodes > 1``: the last ``held_out_episodes`` recordings are
      entirely ``HELD_OUT``, the others entirely ``TRAIN``; ``train_fraction``
      is ignored (it is checked and recorded, but episodes define the split).
    * ``n_episodes == 1``: ``train_fraction`` is required and the first
      ``int(train_fraction * T)`` frames are ``TRAIN``, the rest ``HELD_OUT``
      (the pendulum's contiguous split); ``held_out_episodes`` is ignored.

    With the defaults, 4 x 20 s at 30 fps (2400 frames); the held-out
    recording shows 12 periods of the slow mode. No actuation (``n_u = 0``).

    ``meta`` holds::

        source:  "lagsplat.synth.coupled_carts"
        truth:   f_modes_hz         undamped modal natural frequencies (Hz), ascending
                 zeta_modes         modal damping ratios
                 f_modes_damped_hz  f_i sqrt(1 - zeta_i^2)
                 decay_rates_per_s  zeta_i w_i
                 mass, stiffness, damping   [2][2] matrices M, K, C
                 mode_shapes        [2][2] Phi, column i = mode i, Phi^T M Phi = I
                 springs            [k1, k2, k3] (N/m)
                 f_observed_hz      spectral peak (lagsplat.timeseries.spectral_peak_frequency)
                                    of the true cart-1 displacement on the longest held-out
                                    segment (the first of equal ones), the segment the
                                    single-frequency evaluator measures
        x:       [[x1, x2]] true displacements per frame (frame widths)
        episodes: per recording: frames [start, stop), x0 (frame widths), v0 (frame
                 widths / s), modal_amplitude (a_i, the t = 0 envelope of the modal
                 coordinate q_i of q = Phi^T M x)
        split_rule: "episodes" or "train_fraction"
        params:  every argument of this function

    Args:
        size: output ``(W, H)`` pixels (each >= 16).
        fps: frame rate (Hz, > 0).
        duration_s: length of each recording (s, > 0; at least 8 frames).
        f_modes_hz: ``(f_1, f_2)`` undamped modal frequencies (Hz), ascending.
        zeta: damping ratio of both modes, or ``(zeta_1, zeta_2)``, in ``[0, 1)``.
        masses: ``(m1, m2)`` in kg.
        wall_ratio: ``k3 / k1`` (see :meth:`CoupledCarts.from_modes`).
        amplitude: largest ``|x_j|`` in each recording, frame widths, in
            ``(0, MAX_DISPLACEMENT]``.
        n_episodes: number of recordings (>= 1).
        held_out_episodes: trailing recordings held out, ``1 <= . < n_episodes``
            (used when ``n_episodes > 1``).
        train_fraction: contiguous training share in ``(0, 1)``; used (and
            required) only when ``n_episodes == 1``.
        seed: seeds the initial states (``np.random.default_rng(seed)``) and
            the background texture; the system itself does not depend on it.

    Returns:
        A validated :class:`~lagsplat.io.clip.Clip` with ``episode`` set.

    Raises:
        ValueError: on invalid arguments, an infeasible system (see
            :meth:`CoupledCarts.from_modes`), or a split leaving fewer than 2
            training or 8 held-out frames.
    """
    fps_f, dur = check_timing(fps, duration_s)
    W, H = parse_size(size, 16)
    amp = float(amplitude)
    if not (math.isfinite(amp) and 0.0 < amp <= MAX_DISPLACEMENT):
        raise ValueError(f"amplitude must be in (0, {MAX_DISPLACEMENT}] frame widths, got {amplitude!r}")
    n_ep, n_ho = int(n_episodes), int(held_out_episodes)
    if n_ep != n_episodes or n_ep < 1:
        raise ValueError(f"n_episodes must be an integer >= 1, got {n_episodes!r}")
    if n_ho != held_out_episodes:
        raise ValueError(f"held_out_episodes must be an integer, got {held_out_episodes!r}")
    tf = None
    if train_fraction is not None:
        tf = check_train_fraction(train_fraction)
    T_e = round(dur * fps_f)
    if T_e < 8:
        raise ValueError(f"each episode has {T_e} frames; need at least 8 (increase duration_s or fps)")
    T = n_ep * T_e
    split = np.empty(T, np.int8)
    if n_ep > 1:
        if not (1 <= n_ho < n_ep):
            raise ValueError(
                f"held_out_episodes must be in [1, n_episodes - 1] = [1, {n_ep - 1}], got {held_out_episodes!r}"
            )
        split_rule = "episodes"
        split[: (n_ep - n_ho) * T_e] = TRAIN
        split[(n_ep - n_ho) * T_e :] = HELD_OUT
    else:
        if tf is None:
            raise ValueError("a single episode (n_episodes = 1) needs train_fraction for a contiguous split")
        split_rule = "train_fraction"
        n_train = contiguous_train_frames(tf, T)
        split[:n_train] = TRAIN
        split[n_train:] = HELD_OUT

    system = CoupledCarts.from_modes(f_modes_hz, zeta, masses, wall_ratio)
    rng = np.random.default_rng(int(seed))
    xs, episodes = [], []
    for e in range(n_ep):
        x0, v0, a = _episode_start(system, rng)
        x, _, _ = simulate_coupled_carts(system, x0, v0, fps_f, T_e)
        scale = amp / float(np.max(np.abs(x)))
        xs.append(x * scale)
        episodes.append(
            {
                "frames": [e * T_e, (e + 1) * T_e],
                "x0": [float(v) for v in x0 * scale],
                "v0": [float(v) for v in v0 * scale],
                "modal_amplitude": [float(v) for v in a * scale],
            }
        )
    x_all = np.concatenate(xs)
    images = render_coupled_carts(x_all, size=(W, H), seed=seed)
    t = np.arange(T, dtype=np.float64) / fps_f
    episode = np.repeat(np.arange(n_ep, dtype=np.int16), T_e)

    held = segments(split, HELD_OUT, episode)
    ho = max(held, key=len)
    truth = system.truth()
    truth["f_observed_hz"] = float(spectral_peak_frequency(x_all[ho, 0], 1.0 / fps_f))
    meta: dict[str, Any] = {
        "source": "lagsplat.synth.coupled_carts",
        "truth": truth,
        "x": x_all.tolist(),
        "episodes": episodes,
        "split_rule": split_rule,
        "params": {
            "size": [W, H],
            "fps": fps_f,
            "duration_s": dur,
            "f_modes_hz": [float(v) for v in _pair(f_modes_hz, "f_modes_hz")],
            "zeta": [float(v) for v in _pair(zeta, "zeta")],
            "masses": [float(v) for v in _pair(masses, "masses")],
            "wall_ratio": float(wall_ratio),
            "amplitude": amp,
            "n_episodes": n_ep,
            "held_out_episodes": n_ho,
            "train_fraction": tf,
            "seed": int(seed),
        },
    }
    clip = Clip(images=images, t=t, split=split, meta=meta, episode=episode)
    return clip.validate("lagsplat.synth.coupled_carts")
