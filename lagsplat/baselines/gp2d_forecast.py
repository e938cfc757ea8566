"""GP-2D, the forecaster: a free, black-box graph network over a key-point history, rolled out autoregressively.

The structure of GaussianPrediction's forecaster (Zhao et al., SIGGRAPH 2024; Mao et al.'s
trajectory-dependency GCN without its DCT step), re-implemented for the 2-D key points of
:mod:`lagsplat.baselines.gp2d_field`. Two graph networks, one over the ``2 K`` key-point coordinates
(x of every key point, then y), one over the ``2 K`` rotation components (cos, then sin; renormalised
per key point). Each node's input is its value over the last ``history`` frames; the output is the
absolute next value. Each network: a graph convolution ``Y = A (X W) + b`` (dense learnable
adjacency ``A``) from ``history`` to ``hidden`` features, BatchNorm over all node features, tanh;
``stages`` residual blocks of two such layers; a per-node head ``Linear -> ReLU -> Linear``.

The forecaster sees nothing but past key-point states: no time, time step, mass, stiffness,
damping, energy or actuation. Whatever physics it shows, it learned from the pattern of past states.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

from lagsplat.baselines.gp2d_field import GP2DConfig

__all__ = ["GraphConv", "GCN", "KeypointForecaster", "train_forecaster", "forecast"]


class GraphConv(nn.Module):
    """``Y = A (X W) + b`` over ``n_nodes`` nodes: ``X [B,n,n_in] -> Y [B,n,n_out]``; ``A`` and ``W`` start ``U(+-1/sqrt(n_out))``."""

    def __init__(self, n_in: int, n_out: int, n_nodes: int) -> None:
        super().__init__()
        s = 1.0 / math.sqrt(n_out)
        self.W = nn.Parameter(torch.empty(n_in, n_out).uniform_(-s, s))
        self.A = nn.Parameter(torch.empty(n_nodes, n_nodes).uniform_(-s, s))
        self.b = nn.Parameter(torch.empty(n_out).uniform_(-s, s))

    def forward(self, x: Tensor) -> Tensor:
        return torch.matmul(self.A, x @ self.W) + self.b


class _Layer(nn.Module):
    """Graph convolution, BatchNorm over the flattened ``n x n_out`` features, tanh."""

    def __init__(self, n_in: int, n_out: int, n_nodes: int) -> None:
        super().__init__()
        self.gc, self.bn = GraphConv(n_in, n_out, n_nodes), nn.BatchNorm1d(n_nodes * n_out)

    def forward(self, x: Tensor) -> Tensor:
        y = self.gc(x)
        return torch.tanh(self.bn(y.flatten(1)).view_as(y))


class GCN(nn.Module):
    """``[B, n_nodes, history] -> [B, n_nodes]``: input layer, ``stages`` residual blocks of two layers, per-node head."""

    def __init__(self, n_nodes: int, history: int = 10, hidden: int = 128, stages: int = 6) -> None:
        super().__init__()
        self.inp = _Layer(history, hidden, n_nodes)
        self.blocks = nn.ModuleList(nn.Sequential(_Layer(hidden, hidden, n_nodes), _Layer(hidden, hidden, n_nodes)) for _ in range(stages))
        self.head = nn.Sequential(nn.Linear(hidden, hidden), nn.ReLU(), nn.Linear(hidden, 1))

    def forward(self, x: Tensor) -> Tensor:
        y = self.inp(x)
        for blk in self.blocks:
            y = y + blk(y)
        return self.head(y).squeeze(-1)


class KeypointForecaster(nn.Module):
    """Next key-point state from the last ``history`` ones: ``[B, history, K, 4] -> [B, K, 4]`` (x, y, cos, sin).

    Args:
        n_keypoints: ``K``.
        cfg: the ``gcn_*`` settings of :class:`~lagsplat.baselines.gp2d_field.GP2DConfig`.
    """

    def __init__(self, n_keypoints: int, cfg: GP2DConfig) -> None:
        super().__init__()
        self.K, self.history = int(n_keypoints), int(cfg.gcn_history)
        self.pos = GCN(2 * self.K, cfg.gcn_history, cfg.gcn_hidden, cfg.gcn_stages)
        self.rot = GCN(2 * self.K, cfg.gcn_history, cfg.gcn_hidden, cfg.gcn_stages)

    def forward(self, hist: Tensor) -> Tensor:
        B = hist.shape[0]
        nodes = hist.permute(0, 3, 2, 1)  # [B,4,K,H]: channel-major nodes
        p = self.pos(nodes[:, :2].reshape(B, 2 * self.K, self.history)).view(B, 2, self.K)
        r = self.rot(nodes[:, 2:].reshape(B, 2 * self.K, self.history)).view(B, 2, self.K)
        r = r / r.norm(dim=1, keepdim=True).clamp_min(1e-8)
        return torch.cat([p, r], 1).transpose(1, 2)


def train_forecaster(states: np.ndarray | Tensor, cfg: GP2DConfig, seed: int = 0) -> tuple[KeypointForecaster, dict[str, Any]]:
    """Fit :class:`KeypointForecaster` on the fitted key-point states ``[T,K,4]`` of the training frames (in time order, evenly spaced).

    Windows of ``history`` states -> the next one; batch ``min(gcn_batch, windows)``, shuffled, last partial batch
    dropped; Adam (eps 1e-15) with cosine annealing from ``gcn_lr`` to ``gcn_lr_min`` over ``gcn_epochs`` (fewer when
    they would exceed ``gcn_max_steps`` steps). Loss:
    mean over key points of the position error's norm plus that of the rotation error.

    Returns:
        ``(model in eval mode, history)`` with ``loss`` per epoch (every 10th), ``epochs``, ``steps`` and ``train_s``.

    Raises:
        ValueError: with fewer than ``history + 1`` states.
    """
    S = torch.as_tensor(np.asarray(states), dtype=torch.float32)
    H = int(cfg.gcn_history)
    if len(S) < H + 1:
        raise ValueError(f"the forecaster needs at least {H + 1} fitted states, got {len(S)}")
    torch.manual_seed(2024 * seed)
    rng = np.random.default_rng(2024 * seed)
    X = torch.stack([S[i : i + H] for i in range(len(S) - H)])
    Y = S[H:]
    model = KeypointForecaster(S.shape[1], cfg)
    batch = min(int(cfg.gcn_batch), len(X))
    per_epoch = len(X) // batch
    epochs = int(cfg.gcn_epochs) if not cfg.gcn_max_steps else max(1, min(int(cfg.gcn_epochs), math.ceil(cfg.gcn_max_steps / per_epoch)))
    opt = torch.optim.Adam(model.parameters(), lr=cfg.gcn_lr, eps=1e-15)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=epochs, eta_min=cfg.gcn_lr_min)
    hist: dict[str, Any] = {"loss": [], "epochs": epochs, "steps": epochs * per_epoch}
    t0 = time.perf_counter()
    model.train()
    for ep in range(epochs):
        perm = torch.as_tensor(rng.permutation(len(X)))
        tot, n = 0.0, 0
        for i in range(0, len(X) - batch + 1, batch):
            b = perm[i : i + batch]
            pred = model(X[b])
            loss = (pred[..., :2] - Y[b][..., :2]).norm(dim=-1).mean() + (pred[..., 2:] - Y[b][..., 2:]).norm(dim=-1).mean()
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            tot, n = tot + float(loss.detach()), n + 1
        sched.step()
        if ep % 10 == 0 or ep == epochs - 1:
            hist["loss"].append((ep, tot / max(n, 1)))
    hist["train_s"] = time.perf_counter() - t0
    return model.eval(), hist


@torch.inference_mode()
def forecast(model: KeypointForecaster, history: np.ndarray | Tensor, n_steps: int) -> np.ndarray:
    """Autoregressive rollout: predict, append, slide the window; ``history [>= H, K, 4]`` -> ``[n_steps, K, 4]`` (float32)."""
    h = torch.as_tensor(np.asarray(history), dtype=torch.float32)[-model.history :][None]
    out = np.empty((int(n_steps), model.K, 4), np.float32)
    for i in range(int(n_steps)):
        nxt = model(h)
        out[i] = nxt[0].numpy()
        h = torch.cat([h[:, 1:], nxt[:, None]], 1)
    return out
