"""The "plain damped oscillator": a linear model with the Lagrangian's interface, fitted in closed form.

The stand-in identified model of the latent-level tests and benchmark
(``benchmarks/diagnosis_latent.py``): no Stage 1, no Stage 2 training, only
the linear terms a Lagrangian of the paper's class has near its rest state
(paper §3.3: stiffness, Rayleigh damping, input map).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch
from scipy.ndimage import gaussian_filter1d

__all__ = ["LinearOscillator", "fit_linear_oscillator"]


class LinearOscillator(torch.nn.Module):
    """A linear model with the Lagrangian's interface: ``qddot = -K (q - q0) - C qdot + B u`` (unit inertia).

    The stand-in "plain damped oscillator" of the latent-level tests and
    benchmark (no Stage 1, no Stage 2 training): fitted in closed form by
    :func:`fit_linear_oscillator`.

    Args:
        K, C: ``[d,d]`` stiffness and damping (per s^2, per s).
        q0: ``[d]`` rest position.
        B: ``[d,n_u]`` input gain (``None``: no actuation).
    """

    def __init__(self, K: np.ndarray, C: np.ndarray, q0: np.ndarray, B: np.ndarray | None = None) -> None:
        super().__init__()
        d = len(q0)
        self.d = d
        self.register_buffer("K", torch.as_tensor(np.asarray(K, np.float64).reshape(d, d)))
        self.register_buffer("C", torch.as_tensor(np.asarray(C, np.float64).reshape(d, d)))
        self.register_buffer("q0", torch.as_tensor(np.asarray(q0, np.float64).reshape(d)))
        B = np.zeros((d, 0)) if B is None else np.asarray(B, np.float64).reshape(d, -1)
        self.register_buffer("B", torch.as_tensor(B))
        self.n_u = int(B.shape[1])

    def acceleration(self, q: torch.Tensor, qdot: torch.Tensor, f_ext: torch.Tensor | None = None, u: torch.Tensor | None = None) -> torch.Tensor:
        """``qddot [B,d]``; ``f_ext [B,d]`` adds directly (unit inertia); ``u [B,n_u]``."""
        K, C = self.K.to(q.dtype), self.C.to(q.dtype)
        a = -(q - self.q0.to(q.dtype)) @ K.T - qdot @ C.T
        if f_ext is not None:
            a = a + f_ext
        if u is not None and self.n_u:
            a = a + u.to(q.dtype) @ self.B.to(q.dtype).T
        return a

    def mass_matrix(self, q: torch.Tensor) -> torch.Tensor:
        """Identity inertia ``[B,d,d]``."""
        return torch.eye(self.d, dtype=q.dtype).expand(q.shape[0], self.d, self.d)

    def modal_analysis(self) -> dict[str, np.ndarray]:
        """``{"f_hz", "zeta"}`` of the linear modes (sorted by frequency)."""
        d = self.d
        A = np.zeros((2 * d, 2 * d))
        A[:d, d:] = np.eye(d)
        A[d:, :d] = -self.K.numpy()
        A[d:, d:] = -self.C.numpy()
        lam = np.linalg.eigvals(A)
        lam = lam[lam.imag > 1e-12]
        order = np.argsort(np.abs(lam))
        lam = lam[order]
        return {"f_hz": np.abs(lam) / (2 * math.pi), "zeta": -lam.real / np.abs(lam)}


def fit_linear_oscillator(
    q_segments: Sequence[np.ndarray], dt: float, u_segments: Sequence[np.ndarray] | None = None, sigma: float = 2.0
) -> LinearOscillator:
    """Least-squares linear oscillator on smoothed trajectories (the "plain model" stand-in).

    Regresses ``qddot`` on ``[q, qdot, 1, u]`` (Gaussian derivative filters of
    ``sigma`` frames, ``2 ceil(3 sigma)`` edge samples dropped per segment).

    Args:
        q_segments: list of ``[m,d]`` trajectories.
        dt: frame interval, s.
        u_segments: list of ``[m,n_u]`` actuation, or ``None``.
        sigma: smoothing, frames.

    Returns:
        The fitted :class:`LinearOscillator`.

    Raises:
        ValueError: if there are fewer samples than unknowns.
    """
    rows, ys = [], []
    trim = int(math.ceil(3 * sigma))
    for k, q in enumerate(q_segments):
        q = np.asarray(q, np.float64)
        if len(q) <= 2 * trim + 2:
            continue
        f = [gaussian_filter1d(q, sigma, axis=0, order=o, mode="nearest") / dt**o for o in range(3)]
        u = np.zeros((len(q), 0)) if u_segments is None else np.asarray(u_segments[k], np.float64).reshape(len(q), -1)
        X = np.concatenate([f[0], f[1], np.ones((len(q), 1)), gaussian_filter1d(u, sigma, axis=0, mode="nearest") if u.shape[1] else u], 1)
        rows.append(X[trim:-trim])
        ys.append(f[2][trim:-trim])
    if not rows:
        raise ValueError("fit_linear_oscillator: no segment is long enough")
    X, Y = np.concatenate(rows), np.concatenate(ys)
    if len(X) <= X.shape[1]:
        raise ValueError(f"fit_linear_oscillator: {len(X)} samples for {X.shape[1]} unknowns")
    W, *_ = np.linalg.lstsq(X, Y, rcond=None)
    d = Y.shape[1]
    K, C, b = -W[:d].T, -W[d : 2 * d].T, W[2 * d]
    B = W[2 * d + 1 :].T if X.shape[1] > 2 * d + 1 else None
    q0 = np.linalg.lstsq(K, b, rcond=None)[0]
    return LinearOscillator(K, C, q0, B)
