"""A latent neural ODE on the frozen LaGSplat chart: the prior removed, the renderer kept (paper §4.3).

The state ``x = (q, qdot)`` of the whitened chart evolves by an unconstrained vector field,
``dx/dt = f_theta(x, u)`` (Chen et al., NeurIPS 2018), an MLP with no mass, stiffness, damping or
energy: nothing makes it dissipative, nor even ties the derivative of ``q`` to ``qdot``. It is
fitted on the same one-step windows, loss, optimiser, budget and model selection as Stage 2
(:func:`lagsplat.train.stage2.train_stage2`, paper Eq. 8 and §3.3), but each step is integrated
by ``torchdiffeq.odeint`` (fixed-step RK4 over the window's ``h = k dt``), and so are its rollouts.
Whatever separates it from LaGSplat on the extrapolation protocol is then the Lagrangian prior alone.
"""

from __future__ import annotations

import copy
import math
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn
from torchdiffeq import odeint

from lagsplat import metrics
from lagsplat.chart import Chart
from lagsplat.dynamics.integrators import initial_state
from lagsplat.train.stage2 import Stage2Config, selection_replaces, training_windows
from lagsplat.train.shooting import step_error

__all__ = ["LatentNeuralODE", "train_neural_ode", "ode_rollout"]


class LatentNeuralODE(nn.Module):
    """``d(q, qdot)/dt = f_theta(q, qdot, u)``: an MLP ``[2d + n_u] -> [2d]`` with SiLU activations.

    Args:
        d: latent dimension.
        n_u: actuation channels (read at the window's start, held over the step).
        hidden: widths of the hidden layers (Stage 2's ``hidden`` for an equal budget).
    """

    def __init__(self, d: int, n_u: int = 0, hidden: tuple[int, ...] = (64, 64)) -> None:
        super().__init__()
        self.d, self.n_u = int(d), int(n_u)
        layers: list[nn.Module] = []
        width = 2 * self.d + self.n_u
        for h in hidden:
            layers += [nn.Linear(width, int(h)), nn.SiLU()]
            width = int(h)
        layers.append(nn.Linear(width, 2 * self.d))
        self.net = nn.Sequential(*layers)
        self.u: Tensor | None = None  # actuation held over the current integration, [B,n_u]

    def forward(self, t: Tensor, x: Tensor) -> Tensor:
        """The vector field at ``x [B,2d]`` (``t`` unused: autonomous given ``u``)."""
        inp = x if self.u is None or self.n_u == 0 else torch.cat([x, self.u], -1)
        return self.net(inp)

    def step(self, q: Tensor, qdot: Tensor, h: float, u: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """One RK4 step of length ``h`` (s) from ``q, qdot [B,d]``: ``(q1, qdot1)``."""
        self.u = u
        x = odeint(self, torch.cat([q, qdot], -1), torch.tensor([0.0, float(h)]), method="rk4")[-1]
        return x[..., : self.d], x[..., self.d :]


@torch.no_grad()
def ode_rollout(model: LatentNeuralODE, q0: Tensor, qdot0: Tensor, dt: float, n_states: int, u: np.ndarray | None = None) -> Tensor:
    """Free rollout ``[B, n_states, d]`` of positions, frames ``dt`` s apart (fixed-step RK4 at ``dt``).

    Args:
        q0, qdot0: ``[B,d]`` initial state.
        u: ``[B, n_states, n_u]`` actuation per frame (held over each frame), or ``None``.
    """
    qs = [q0]
    q, v = q0, qdot0
    for i in range(n_states - 1):
        ui = None if u is None else torch.as_tensor(u[:, i], dtype=q.dtype)
        q, v = model.step(q, v, dt, ui)
        qs.append(q)
    return torch.stack(qs, 1)


def _selection_error(model: LatentNeuralODE, q: np.ndarray, dt: float, G: np.ndarray, horizon: int, starts: np.ndarray, q_std: float,
                     u: np.ndarray | None) -> float:  # fmt: skip
    """Latent NRMSE of free rollouts of ``horizon`` states from ``starts`` (Stage 2's selection, paper §3.3)."""
    q0, v0 = initial_state(q, starts, dt)
    u_w = None if u is None or u.shape[1] == 0 else np.stack([u[s : s + horizon] for s in starts])
    pred = ode_rollout(model, q0, v0, dt, horizon, u_w).numpy()
    if not np.isfinite(pred).all():
        return float("inf")
    return metrics.latent_nrmse(pred, np.stack([q[s : s + horizon] for s in starts]), G, q_std)


def train_neural_ode(chart: Chart, cfg: Stage2Config, seed: int = 0) -> tuple[LatentNeuralODE, dict[str, Any]]:
    """Fit :class:`LatentNeuralODE` on the chart's training frames with Stage 2's windows, loss and budget.

    Loss (paper Eq. 8): ``w_q |q1_hat - q1|_A^2 / d + w_v |h (v1_hat - v1)|_A^2 / d`` over the one-step
    windows of :func:`~lagsplat.train.stage2.one_step_windows` (stride ``k``, ``h = k dt``); Adam,
    ``cfg.epochs`` epochs of ``cfg.windows_per_epoch`` windows; every ``select_every`` epochs the
    model is rolled out over ``select_periods`` natural periods of the training frames and kept by
    Stage 2's rule (:func:`~lagsplat.train.stage2.selection_replaces`: by default the last epoch's model).

    Args:
        chart: the frozen chart (training frames only).
        cfg: Stage 2's settings (the budget; ``hidden`` sizes the MLP).
        seed: RNG seed.

    Returns:
        ``(model, history)`` with ``loss``, ``select_nrmse``, ``selected_epoch``, ``selected_nrmse``, ``f_train_hz``.

    Raises:
        ValueError: if no training segment is long enough for one window.
    """
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    w = training_windows(chart, cfg, seed, "neural-ODE")
    dt, d, k = w.dt, chart.d, cfg.stride
    Q0, V0, Q1, V1, U0 = w.Q0, w.V0, w.Q1, w.V1, w.U0
    A = torch.as_tensor(chart.A, dtype=torch.float32)
    sel, sel_u, sel_h, starts, q_std, G, f_train = w.select_q, w.select_u, w.select_horizon, w.select_starts, w.q_std, w.G, w.f_train

    model = LatentNeuralODE(d, chart.n_u, tuple(cfg.hidden))
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    h = k * dt
    hist: dict[str, Any] = {"loss": [], "select_nrmse": []}
    best = (math.inf, copy.deepcopy(model.state_dict()), -1)
    for ep in range(cfg.epochs):
        perm = rng.permutation(len(Q0))[: min(len(Q0), cfg.windows_per_epoch)]
        tot, cnt = 0.0, 0
        for i in range(0, len(perm), cfg.batch):
            b = torch.as_tensor(perm[i : i + cfg.batch])
            q1, v1 = model.step(Q0[b], V0[b], h, U0[b] if chart.n_u else None)
            eq, ev = q1 - Q1[b], h * (v1 - V1[b])
            loss = step_error(eq, ev, A, cfg.w_q, cfg.w_v).mean() / d
            if not torch.isfinite(loss):
                continue
            opt.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(model.parameters(), cfg.grad_clip)
            opt.step()
            tot, cnt = tot + float(loss.detach()), cnt + 1
        hist["loss"].append(tot / max(cnt, 1))
        if (ep + 1) % cfg.select_every == 0 or ep == cfg.epochs - 1:
            err = _selection_error(model, sel, dt, G, sel_h, starts, q_std, sel_u)
            hist["select_nrmse"].append((ep, err))
            if selection_replaces(err, best[0], best[2], cfg):
                best = (err, copy.deepcopy(model.state_dict()), ep)
    model.load_state_dict(best[1])
    hist.update(selected_epoch=best[2], selected_nrmse=best[0], f_train_hz=f_train)
    return model.eval(), hist
