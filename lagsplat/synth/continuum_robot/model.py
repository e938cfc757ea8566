"""The soft continuum robot: argument checks, the model (:class:`ContinuumRobot`) and its modal analysis.

Part of :mod:`lagsplat.synth.continuum_robot` (its docstring describes the model).
"""

from __future__ import annotations

import functools
import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from scipy.linalg import eig, eigh
from scipy.optimize import root

from lagsplat.synth.continuum_robot.constants import GRAVITY, RENDER_NODES, SEGMENTS
from lagsplat.synth.continuum_robot.kernels import (
    backbone_kinematics,
    robot_acceleration,
)


def check_segments(n_segments: Any) -> int:
    """``n_segments`` as an int in {1, 2}; ValueError otherwise."""
    if isinstance(n_segments, bool) or not isinstance(n_segments, (int, np.integer)) or int(n_segments) not in SEGMENTS:
        raise ValueError(f"n_segments must be 1 or 2 (the Krauss robots), got {n_segments!r}")
    return int(n_segments)


def check_positive(value: Any, name: str, allow_zero: bool = False) -> float:
    """``value`` as a positive (or, with ``allow_zero``, non-negative) finite float.

    Raises:
        ValueError: naming ``name`` and the value.
    """
    try:
        v = float(value)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a number, got {value!r}") from exc
    if not math.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        raise ValueError(f"{name} must be {'non-negative' if allow_zero else 'positive'}, got {value!r}")
    return v


def per_segment(value: Any, n: int, name: str, allow_zero: bool = False) -> tuple[float, ...]:
    """A scalar (for every segment) or ``n`` values, each finite and positive."""
    vals = [value] * n if np.ndim(value) == 0 else list(np.ravel(np.asarray(value, dtype=object)))
    if len(vals) != n:
        raise ValueError(f"{name} needs one value per segment ({n}), got {value!r}")
    return tuple(check_positive(v, name, allow_zero) for v in vals)


def pressure_keys(n_segments: int) -> list[str]:
    """NPZ pressure keys of an ``n_segments`` robot: ``["p1", "p2"]`` or ``["p1", "p2", "p3", "p4"]``.

    Segment ``i`` owns ``p{2i-1}`` (image-left chamber) and ``p{2i}`` (image-right chamber).

    Raises:
        ValueError: if ``n_segments`` is not 1 or 2.
    """
    n = check_segments(n_segments)
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
        n = check_segments(self.n_segments)
        for name in ("length_m", "mass_kg", "k_bend", "k_axial", "b_bend", "b_axial"):
            object.__setattr__(self, name, per_segment(getattr(self, name), n, name))
        object.__setattr__(self, "tip_mass_kg", per_segment(self.tip_mass_kg, n, "tip_mass_kg", allow_zero=True))
        z = per_segment(self.zeta, 2, "zeta") if np.ndim(self.zeta) else (check_positive(self.zeta, "zeta"),) * 2
        if not all(0.0 < v < 1.0 for v in z):
            raise ValueError(f"zeta must be in (0, 1) (under-damped), got {self.zeta!r}")
        object.__setattr__(self, "zeta", z)
        if isinstance(self.n_nodes, bool) or int(self.n_nodes) != self.n_nodes or int(self.n_nodes) < 2:
            raise ValueError(f"n_nodes must be an integer >= 2, got {self.n_nodes!r}")
        object.__setattr__(self, "n_nodes", int(self.n_nodes))
        object.__setattr__(self, "gravity", check_positive(self.gravity, "gravity", allow_zero=True))

    @classmethod
    def default(cls, n_segments: int, **overrides: Any) -> ContinuumRobot:
        """The default robot (module docstring): identical 0.14 m segments, lowest mode 4.63 Hz (1) / 1.55 Hz (2).

        Args:
            n_segments: 1 or 2.
            **overrides: any field of :class:`ContinuumRobot` (scalars apply to every segment).

        Raises:
            ValueError: on a bad ``n_segments`` or an invalid / unknown override.
        """
        n = check_segments(n_segments)
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
        return backbone_kinematics(self._q(q), qd, self._arrays["L0"], self.n_nodes)

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
        return robot_acceleration(self._q(q), self._q(qdot, "qdot"), P, ar["L0"], self.n_nodes, ar["mass"], ar["kdiag"], D, ar["B"], self.gravity)

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

    def backbone(self, q: Any, nodes_per_segment: int = RENDER_NODES) -> tuple[np.ndarray, np.ndarray]:
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


