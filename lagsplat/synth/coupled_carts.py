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

The picture and the clip: :mod:`lagsplat.synth.coupled_carts_clip`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.linalg import eigh, expm

__all__ = ["CoupledCarts", "simulate_coupled_carts", "as_pair", "RAIL_Y", "CART_WIDTH", "CART_HEIGHT", "MAX_DISPLACEMENT"]

#: Rail heights of cart 1 and cart 2, in units of the frame height.
RAIL_Y = (0.38, 0.86)
#: Cart body width (units of the frame width) and height (units of the frame height).
CART_WIDTH = 0.18
CART_HEIGHT = 0.17
#: Largest displacement |x_j| (units of the frame width) the renderer accepts:
#: the cart then still clears the end walls.
MAX_DISPLACEMENT = 0.35


# --------------------------------------------------------------------- physics
def as_pair(value: Any, name: str) -> tuple[float, float]:
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
        m1, m2 = as_pair(masses, "masses")
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
        z = as_pair(zeta, "zeta")
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
        f1, f2 = as_pair(f_modes_hz, "f_modes_hz")
        if not (0.0 < f1 < f2):
            raise ValueError(f"f_modes_hz must be two distinct positive frequencies in ascending order, got {f_modes_hz!r}")
        m1, m2 = as_pair(masses, "masses")
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
