"""A fitted model's acceleration and inertia on numpy states, and its acceleration smoothed like the observed one.

What the residual of :mod:`lagsplat.diagnose.residual` compares the observed
acceleration with: the model's right-hand side of the Euler-Lagrange equation
(paper Eq. 7), evaluated on the de-blurred state and smoothed by the same
Gaussian kernel as the data (see "Differentiation" in that module's docstring).
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np
import torch
from scipy.ndimage import gaussian_filter1d

__all__ = ["AccelerationModel", "model_acceleration", "smoothed_model_acceleration"]


class AccelerationModel(Protocol):
    """What the diagnosis needs of a fitted model: its acceleration (``mass_matrix(q) -> [B,d,d]`` is optional).

    E.g. :class:`~lagsplat.models.lagrangian.Lagrangian` or
    :class:`~lagsplat.diagnose.oscillator.LinearOscillator`.
    """

    def acceleration(self, q: torch.Tensor, qdot: torch.Tensor, f_ext: torch.Tensor | None = None, u: torch.Tensor | None = None) -> torch.Tensor:
        """``qddot [B,d]`` at ``q, qdot [B,d]`` under the external force ``f_ext [B,d]`` and the input ``u [B,n_u]``."""
        ...


def model_acceleration(model: Any, q: np.ndarray, qdot: np.ndarray, u: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """``(a [m,d], M [m,d,d])`` of a model with ``acceleration`` (and optionally ``mass_matrix``; identity otherwise).

    Evaluated without gradients in eval mode, in the dtype of the model's
    parameters (float64 for a model without any); a model in training mode is
    put back into it.

    Args:
        model: an :class:`AccelerationModel`.
        q, qdot: float ``[m,d]`` positions and velocities (per s).
        u: ``[m,n_u]`` actuation, or ``None`` / zero channels (no input passed).

    Returns:
        float64 accelerations (per s^2) and inertias.
    """
    p = next(iter(model.parameters()), None) if hasattr(model, "parameters") else None
    dtype = p.dtype if p is not None else torch.float64
    Q = torch.as_tensor(q, dtype=dtype)
    V = torch.as_tensor(qdot, dtype=dtype)
    U = None if u is None or u.shape[1] == 0 else torch.as_tensor(u, dtype=dtype)
    was_training = getattr(model, "training", False)
    if hasattr(model, "eval"):
        model.eval()
    try:
        with torch.no_grad():
            a = model.acceleration(Q, V, None, u=U) if U is not None else model.acceleration(Q, V)
            M = model.mass_matrix(Q) if hasattr(model, "mass_matrix") else torch.eye(q.shape[1], dtype=dtype).expand(len(q), -1, -1)
    finally:
        if was_training:
            model.train()
    return a.detach().double().numpy(), M.detach().double().numpy()


def smoothed_model_acceleration(
    model: Any, q_t: np.ndarray, qd_t: np.ndarray, u_raw: np.ndarray | None, q_s: np.ndarray, qd_s: np.ndarray,
    u_s: np.ndarray | None, keep: slice, sigma: float,
) -> np.ndarray:
    """``G * a(q, qdot, u)`` of the true state, estimated on the kept samples ``[m,d]``.

    ``G * a(q~, qdot~, u)`` at the de-blurred state, minus the model's local
    linearisation applied to what de-blurring and re-smoothing leave of the
    state, ``J_q (G*q~ - G*q) + J_qdot (G*qdot~ - G*qdot)``: exact for a linear
    model (whatever the spectrum of the motion and the input), and a smooth
    nonlinear model's own curvature is still averaged over the kernel as the
    data are. ``J`` by central differences at the smoothed state.

    Args:
        model: an :class:`AccelerationModel`.
        q_t, qd_t: ``[M,d]`` de-blurred position and velocity of a padded segment.
        u_raw: ``[M,n_u]`` its actuation (``None``: none).
        q_s, qd_s: ``[M,d]`` the smoothed position and velocity.
        u_s: ``[M,n_u]`` the smoothed actuation (``None``: none).
        keep: the samples of the padded segment that are kept.
        sigma: smoothing standard deviation ``G``, frames.

    Returns:
        float64 ``[m,d]`` on the kept samples, per s^2.
    """
    a_raw, _ = model_acceleration(model, q_t, qd_t, u_raw)
    sm = lambda x: gaussian_filter1d(x, sigma, axis=0, mode="nearest", truncate=6.0)
    a = sm(a_raw)[keep]
    dq, dv = (sm(q_t) - q_s)[keep], (sm(qd_t) - qd_s)[keep]
    q0, v0 = q_s[keep], qd_s[keep]
    u0 = None if u_s is None else u_s[keep]
    d = q0.shape[1]
    for j in range(d):
        for base, delta, scale in ((q0, dq, np.std(q0[:, j]) + 1e-12), (v0, dv, np.std(v0[:, j]) + 1e-12)):
            h = 1e-3 * scale
            plus, minus = base.copy(), base.copy()
            plus[:, j] += h
            minus[:, j] -= h
            if base is q0:
                ap, _ = model_acceleration(model, plus, v0, u0)
                am, _ = model_acceleration(model, minus, v0, u0)
            else:
                ap, _ = model_acceleration(model, q0, plus, u0)
                am, _ = model_acceleration(model, q0, minus, u0)
            a = a - (ap - am) / (2 * h) * delta[:, j : j + 1]
    return a
