"""Multi-step (shooting) windows and loss of Stage 2: Eq. 8's Verlet step chained ``K`` times.

Paper Eq. 8 fits one Verlet step per window. Its regressors are the chart's own smoothed ``q`` and
finite-difference ``qdot``, so every frame's chart noise enters the fit as noise in the state it starts
from; a flexible potential then bends to follow it (a softer centre on a plain oscillator). Rolling the
model ``K`` steps from the window's first state and scoring every step lets the noise of one state be
outvoted by the ``K`` states after it, while each window stays well inside one period. This is the
alternative the paper names to its single-step teacher forcing (§3.3 "Fitting the dynamics": unrolling
the prediction over several symplectic steps, Chen et al. 2020; Melchers et al. 2023), at ``K`` times
the cost of a step. ``K = 1`` is Eq. 8 exactly.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from lagsplat.dynamics.integrators import verlet_step

__all__ = ["multi_step_windows", "step_error", "shooting_loss"]


def multi_step_windows(
    q: np.ndarray, dt: float, k: int, K: int, u: np.ndarray | None = None, k_v: int | None = None
) -> tuple[np.ndarray, ...]:
    """Windows of ``K`` Verlet steps of ``h = k dt`` from one contiguous (smoothed) trajectory.

    For every ``s``: start state ``(q[s+k], (q[s+k+k_v] - q[s+k-k_v]) / 2 k_v dt)``, targets
    ``(q[c], (q[c+k_v] - q[c-k_v]) / 2 k_v dt)`` at ``c = s+k+jk`` for ``j = 1..K``, and the actuation at the
    ``K + 1`` step boundaries ``u[s+k+jk]``, ``j = 0..K``. ``K = 1`` gives the windows of
    :func:`~lagsplat.train.stage2.one_step_windows`.

    Args:
        q: ``[n,d]`` trajectory.
        dt: frame interval, s.
        k: stride, frames (``>= 1``).
        K: steps per window (``>= 1``).
        u: ``[n,n_u]`` actuation per frame, or ``None``.
        k_v: half-span of the velocity's central difference, frames, ``1 <= k_v <= k`` (default ``k``;
            1 where the step is integrated in one-frame sub-steps, whose Verlet velocity is exactly the
            one-frame central difference of its positions).

    Returns:
        ``(q0 [m,d], v0 [m,d], Q [m,K,d], V [m,K,d], U [m,K+1,n_u])`` with ``m = max(0, n - (K+2) k)``.

    Raises:
        ValueError: if ``k < 1``, ``K < 1`` or ``k_v`` is outside ``[1, k]``.
    """
    k_v = k if k_v is None else int(k_v)
    if k < 1 or K < 1 or not 1 <= k_v <= k:
        raise ValueError(f"multi-step windows need a stride and a step count >= 1 and 1 <= k_v <= k, got k={k}, K={K}, k_v={k_v}")
    q = np.asarray(q)
    d = q.shape[1]
    u = np.zeros((len(q), 0), np.float32) if u is None else np.asarray(u)
    m = len(q) - (K + 2) * k
    if m <= 0:
        return np.zeros((0, d)), np.zeros((0, d)), np.zeros((0, K, d)), np.zeros((0, K, d)), np.zeros((0, K + 1, u.shape[1]))
    s = np.arange(m)
    v = lambda c: (q[c + k_v] - q[c - k_v]) / (2 * k_v * dt)  # noqa: E731  (central difference at frame c)
    steps = [s + k + j * k for j in range(K + 1)]
    Q = np.stack([q[c] for c in steps[1:]], 1)
    V = np.stack([v(c) for c in steps[1:]], 1)
    U = np.stack([u[c] for c in steps], 1)
    return q[steps[0]], v(steps[0]), Q, V, U


def step_error(eq: Tensor, ev: Tensor, A: Tensor, w_q: float, w_v: float) -> Tensor:
    """Eq. 8's error of one step per sample, ``w_q e_q^T A e_q + w_v e_v^T A e_v`` (``e_v`` already in
    position units, ``h (qdot - V)``): ``eq, ev [B,d]``, ``A [d,d]`` -> ``[B]``."""
    return w_q * torch.einsum("bi,ij,bj->b", eq, A, eq) + w_v * torch.einsum("bi,ij,bj->b", ev, A, ev)


def shooting_loss(
    model, q0: Tensor, v0: Tensor, Q: Tensor, V: Tensor, U: Tensor, h: float, A: Tensor, w_q: float, w_v: float, substeps: int = 1
) -> Tensor:
    """Eq. 8's weighted one-step error averaged over ``K`` chained Verlet steps.

    ``mean_b mean_j [w_q e_q^T A e_q + w_v (h e_v)^T A (h e_v)] / d`` with ``e_q = q_j - Q_j``,
    ``e_v = qdot_j - V_j`` and ``(q_j, qdot_j)`` the model's state after ``j`` steps from ``(q0, v0)``.
    The actuation of step ``j`` is ``U[:, j]`` over its first half and ``U[:, j+1]`` over its second
    (the one-step fit's rule). With ``substeps = n`` each step of ``h`` is ``n`` Verlet steps of ``h / n``
    (the frame interval, :meth:`~lagsplat.train.stage2_config.Stage2Config.substeps`).

    Args:
        model: the Lagrangian (anything :func:`~lagsplat.dynamics.integrators.verlet_step` accepts).
        q0, v0: ``[B,d]`` start states.
        Q, V: ``[B,K,d]`` targets.
        U: ``[B,K+1,n_u]`` actuation at the step boundaries (``n_u = 0``: none).
        h: step, s.
        A: ``[d,d]`` metric of the error (the chart's ``G_bar``, whitened).
        w_q, w_v: weights of the position and velocity terms.
        substeps: Verlet steps per step of ``h`` (``>= 1``).

    Returns:
        scalar loss.
    """
    K, d = Q.shape[1], Q.shape[2]
    q, v, loss = q0, v0, torch.zeros((), dtype=q0.dtype, device=q0.device)
    for j in range(K):
        u_j = None if U.shape[2] == 0 else (lambda t, a=U[:, j], b=U[:, j + 1]: a if t < 0.5 * h else b)  # noqa: E731
        for i in range(substeps):
            q, v = verlet_step(model, q, v, h / substeps, u=u_j, t=i * h / substeps)
        eq, ev = q - Q[:, j], h * (v - V[:, j])
        loss = loss + step_error(eq, ev, A, w_q, w_v).mean()
    return loss / (K * d)
