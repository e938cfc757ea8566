"""GP-2D, the fitted part: canonical 2-D Gaussians, a time-conditioned deformation field, motion distilled into key points.

GP-2D is this project's re-implementation, in the image plane and for the CPU, of the
motion-prediction structure of GaussianPrediction (Zhao et al., SIGGRAPH 2024); it is not the
original code. What it keeps (the original's stages, at CPU scale):

1. **Canonical Gaussians** in normalised image coordinates ``[-1, 1]^2`` (x right, y down): centre
   ``mu``, log-scales, angle ``theta``, colour, opacity (initial 0.1) and a motion feature ``m``
   (initial ``U(+-1e-3)``), on a jittered grid coloured from the first frame. A learned static
   background image (initialised to the per-pixel median of the frames) stands behind them, since
   real clips have textured backgrounds.
2. **Stage 1, per-Gaussian deformation**: an MLP ``D([m, gamma(mu + noise), gamma(t)]) -> (dx, dy, dphi)``
   with the sinusoidal encoding ``gamma`` (10 frequencies for positions, 6 for time), ``mu``
   detached and jittered by noise decaying to 0 over the first sixth of the iterations.
3. **Key points**: K-means on ``[mu, m]`` gives key points ``p_j`` with features ``f_j``; each
   Gaussian follows a convex blend of its ``k`` nearest key points (joint space ``[mu, 0.5 m]``)
   with weights from a small network of its canonical position. Translations are blended, rotations
   blended as unit complex numbers and renormalised (not linear blend skinning, as in the original).
   Stage 2 freezes the Gaussians; stage 3 trains everything.

Loss: ``0.8 L1 + 0.2 (1 - SSIM)`` (11-tap window, sigma 1.5) plus ``1e-5 mean|m|`` after the warm-up;
Adam (eps 1e-15) with the original's learning rates and log-linear decays over 2/3 of the run
(field, features, positions) or all of it (key points, weight network).

Deviations from the original, for the CPU: a 2-D image-plane renderer (this project's rasteriser)
instead of 3-D splatting with cameras; ``frames_per_step`` frames per step instead of one; a fixed
number of Gaussians (no densification or pruning); the deformation MLP 3 x 128 by default instead of
4 x 256; Fourier features instead of a hash grid in the weight network. The forecaster
(:mod:`lagsplat.baselines.gp2d_forecast`) is 64 wide instead of 128 and trains for at most 2000 steps
instead of 2001 epochs.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

from lagsplat.render.rasterize import rasterize
from lagsplat.train.losses import ssim

__all__ = ["GP2DConfig", "GP2DField", "fit_field", "fourier"]


@dataclass
class GP2DConfig:
    """Settings of GP-2D (``conf/config.yaml``, group ``gp2d``); 0 picks the size rule of :meth:`resolved`.

    Attributes:
        n_gaussians: canonical Gaussians (0: a quarter of the pixels, within [256, 4096]).
        n_keypoints: key points ``K_kp`` (0: 16, 32 or 48 for frames nearest, in log pixel count, to 32^2, 64^2 or 128^2).
        k_neighbours: key points per Gaussian (0: 4 when ``K_kp <= 16``, else 6).
        feature_dim: motion-feature dimension ``F_m``.
        hidden: widths of the deformation MLP.
        iterations: field iterations ``I`` (0: 6k, 12k or 20k by the same rule).
        frames_per_step: training frames per optimiser step.
        gcn_history, gcn_stages, gcn_hidden: the forecaster's input steps, residual blocks and width (the original: 128).
        gcn_epochs, gcn_lr, gcn_lr_min, gcn_batch: its training (cosine annealing from ``gcn_lr`` to ``gcn_lr_min``).
        gcn_max_steps: at most this many optimiser steps in all (fewer epochs when the windows make more; 0: no cap).
    """

    n_gaussians: int = 0
    n_keypoints: int = 0
    k_neighbours: int = 0
    feature_dim: int = 32
    hidden: tuple[int, ...] = (128, 128, 128)
    iterations: int = 0
    frames_per_step: int = 4
    gcn_history: int = 10
    gcn_stages: int = 6
    gcn_hidden: int = 64
    gcn_epochs: int = 2001
    gcn_lr: float = 1e-2
    gcn_lr_min: float = 1e-4
    gcn_batch: int = 32
    gcn_max_steps: int = 2000

    def resolved(self, height: int, width: int) -> "GP2DConfig":
        """A copy with every 0 replaced by its size rule for ``height x width`` frames."""
        from dataclasses import replace

        px = int(height) * int(width)
        n = self.n_gaussians or int(min(4096, max(256, px // 4)))
        size = 0 if px <= 32 * 64 else 1 if px <= 64 * 128 else 2  # the nearest of 32^2, 64^2, 128^2 in log pixel count
        kp = self.n_keypoints or (16, 32, 48)[size]
        k = self.k_neighbours or (4 if kp <= 16 else 6)
        it = self.iterations or (6000, 12000, 20000)[size]
        return replace(self, n_gaussians=n, n_keypoints=kp, k_neighbours=min(k, kp), iterations=it, hidden=tuple(self.hidden))


def fourier(x: Tensor, n_freq: int) -> Tensor:
    """``gamma(x) = [sin(2^l x), cos(2^l x)]``, ``l = 0..n_freq-1``, without ``x`` itself: ``[..., c] -> [..., 2 c n_freq]``."""
    f = 2.0 ** torch.arange(n_freq, dtype=x.dtype)
    xf = x[..., None] * f
    return torch.cat([xf.sin(), xf.cos()], -1).flatten(-2)


class DeformMLP(nn.Module):
    """``D([a, gamma(t)])``: an MLP whose first layer is split into a per-primitive part (``a [N, n_a]``) and a per-frame
    part (``gamma(t) [B, n_t]``), so the per-primitive product is computed once per step, not once per frame."""

    def __init__(self, n_a: int, n_t: int, hidden: tuple[int, ...], n_out: int) -> None:
        super().__init__()
        self.first_a = nn.Linear(n_a, int(hidden[0]))
        self.first_t = nn.Linear(n_t, int(hidden[0]), bias=False)
        self.rest = _mlp(int(hidden[0]), tuple(hidden[1:]), n_out)
        with torch.no_grad():  # start at the canonical state
            self.rest[-1].weight.mul_(1e-2)
            self.rest[-1].bias.zero_()

    def forward(self, a: Tensor, t_enc: Tensor) -> Tensor:
        """``a [N,n_a]`` or ``[B,N,n_a]``, ``t_enc [B,n_t]`` -> ``[B,N,n_out]``."""
        h = self.first_a(a)
        h = (h if h.dim() == 3 else h[None]) + self.first_t(t_enc)[:, None]
        return self.rest(torch.relu(h))


def _mlp(n_in: int, hidden: tuple[int, ...], n_out: int) -> nn.Sequential:
    layers: list[nn.Module] = []
    for h in hidden:
        layers += [nn.Linear(n_in, int(h)), nn.ReLU()]
        n_in = int(h)
    layers.append(nn.Linear(n_in, n_out))
    return nn.Sequential(*layers)


class GP2DField(nn.Module):
    """Canonical Gaussians, the deformation MLP ``D`` and (after :meth:`init_keypoints`) the key points.

    Args:
        first: ``[3,H,W]`` first frame in [0, 1] (colours of the initial grid).
        background: ``[3,H,W]`` initial background image in [0, 1].
        cfg: resolved :class:`GP2DConfig`.
        generator: the RNG of the grid jitter and the features.
    """

    L_POS, L_TIME, L_WEIGHT = 10, 6, 6

    def __init__(self, first: Tensor, background: Tensor, cfg: GP2DConfig, generator: torch.Generator) -> None:
        super().__init__()
        _, H, W = first.shape
        self.height, self.width, self.cfg = int(H), int(W), cfg
        n, side = cfg.n_gaussians, math.ceil(math.sqrt(cfg.n_gaussians))
        g = (torch.arange(side, dtype=torch.float32) + 0.5) / side * 2 - 1
        grid = torch.stack(torch.meshgrid(g, g, indexing="xy"), -1).reshape(-1, 2)[:n]
        mu = grid + (torch.rand(n, 2, generator=generator) - 0.5) * (2.0 / side) * 0.5
        px = ((mu + 1) / 2 * torch.tensor([W, H]) - 0.5).round().long()
        col = first[:, px[:, 1].clamp(0, H - 1), px[:, 0].clamp(0, W - 1)].T
        logit = lambda x: torch.log(x / (1 - x))  # noqa: E731
        self.mu = nn.Parameter(mu)
        self.log_scale = nn.Parameter(torch.full((n, 2), math.log(2.0 / side)))
        self.theta = nn.Parameter(torch.zeros(n))
        self.color_raw = nn.Parameter(logit(col.clamp(0.02, 0.98)))
        self.opacity_raw = nn.Parameter(torch.full((n,), logit(torch.tensor(0.1)).item()))
        self.feature = nn.Parameter((torch.rand(n, cfg.feature_dim, generator=generator) * 2 - 1) * 1e-3)
        self.bg_raw = nn.Parameter(logit(background.clamp(0.02, 0.98)))
        self.deform = DeformMLP(cfg.feature_dim + 4 * self.L_POS, 2 * self.L_TIME, cfg.hidden, 3)
        self.kp_pos = nn.Parameter(torch.zeros(0, 2))
        self.kp_feat = nn.Parameter(torch.zeros(0, cfg.feature_dim))
        self.weight_net = _mlp(4 * self.L_WEIGHT, (64, 64), 2 * cfg.k_neighbours)

    @property
    def n_keypoints(self) -> int:
        """Key points so far (0 before :meth:`init_keypoints`)."""
        return int(self.kp_pos.shape[0])

    def render(self, mu_t: Tensor, theta_t: Tensor) -> Tensor:
        """Composite the Gaussians at centres ``mu_t [B,N,2]`` and angles ``theta_t [B,N]`` over the background: ``[B,3,H,W]``."""
        B, H, W = mu_t.shape[0], self.height, self.width
        half = torch.tensor([W / 2.0, H / 2.0])
        c, s = theta_t.cos(), theta_t.sin()
        R = torch.stack([torch.stack([c, -s], -1), torch.stack([s, c], -1)], -2)  # [B,N,2,2]
        S = torch.exp(self.log_scale)[None] * half  # pixel extents
        RS = R * S[:, :, None, :]
        covs = RS @ RS.transpose(-1, -2)
        colors = torch.cat([torch.sigmoid(self.color_raw), torch.ones(self.mu.shape[0], 1)], -1)
        opac = torch.sigmoid(self.opacity_raw)[None].expand(B, -1)
        out = rasterize((mu_t + 1) * half, covs, opac.contiguous(), colors, H, W)
        return out[:, :3] + (1 - out[:, 3:4]) * torch.sigmoid(self.bg_raw)[None]

    def deform_gaussians(self, t: Tensor, noise_std: float = 0.0) -> tuple[Tensor, Tensor]:
        """Stage 1: per-Gaussian deformation at normalised times ``t [B]``: ``(mu_t [B,N,2], theta_t [B,N])``."""
        mu = self.mu.detach()
        if noise_std > 0:
            mu = mu + noise_std * torch.randn_like(mu)
        d = self.deform(torch.cat([self.feature, fourier(mu, self.L_POS)], -1), fourier(t[:, None], self.L_TIME))
        return self.mu[None] + d[..., :2], self.theta[None] + d[..., 2]

    @torch.no_grad()
    def init_keypoints(self, seed: int) -> None:
        """K-means (scipy ``kmeans2``, k-means++) on ``[mu, m]``: key points at the cluster means, features their centres."""
        from scipy.cluster.vq import kmeans2

        data = torch.cat([self.mu, self.feature], -1).double().numpy()
        centres, _ = kmeans2(data, self.cfg.n_keypoints, minit="++", seed=np.random.default_rng(seed))
        c = torch.as_tensor(centres, dtype=torch.float32)
        self.kp_pos = nn.Parameter(c[:, :2].contiguous())
        self.kp_feat = nn.Parameter(c[:, 2:].contiguous())

    def keypoint_states(self, t: Tensor, noise_std: float = 0.0) -> Tensor:
        """Key-point states ``S [B,K,4]`` = (absolute x, y, cos dphi, sin dphi) at normalised times ``t [B]``."""
        p = self.kp_pos if noise_std <= 0 else self.kp_pos + noise_std * torch.randn_like(self.kp_pos)
        d = self.deform(torch.cat([self.kp_feat, fourier(p, self.L_POS)], -1), fourier(t[:, None], self.L_TIME))
        return torch.cat([self.kp_pos[None] + d[..., :2], d[..., 2:3].cos(), d[..., 2:3].sin()], -1)

    def blend(self, S: Tensor) -> tuple[Tensor, Tensor]:
        """Gaussians driven by key-point states ``S [B,K,4]``: ``(mu_t [B,N,2], theta_t [B,N])``.

        ``Delta mu_i = sum_j w^x_ij (P_j - p_j)``; ``rotation_i = normalise(sum_j w^r_ij R_j)`` composed with ``theta_i``,
        over each Gaussian's ``k`` nearest key points in ``[mu, 0.5 m]`` (rank-ordered weight slots).
        """
        k = self.cfg.k_neighbours
        with torch.no_grad():
            a = torch.cat([self.mu, 0.5 * self.feature], -1)
            b = torch.cat([self.kp_pos, 0.5 * self.kp_feat], -1)
            idx = torch.cdist(a, b).topk(k, largest=False, sorted=True).indices  # [N,k]
        logits = self.weight_net(fourier(self.mu.detach(), self.L_WEIGHT))
        # Dense [N, K_kp] weight matrices (zero off the k neighbours): the products below then reduce in a fixed
        # order, where the backward of a gather ``S[:, idx]`` accumulates with threads in a run-dependent order.
        zeros = torch.zeros(idx.shape[0], S.shape[1], dtype=S.dtype)
        wx = zeros.scatter(1, idx, torch.softmax(logits[:, :k], -1))
        wr = zeros.scatter(1, idx, torch.softmax(logits[:, k:], -1))
        mu_t = self.mu[None] + torch.einsum("nk,bkc->bnc", wx, S[..., :2] - self.kp_pos[None])
        rot = torch.einsum("nk,bkc->bnc", wr, S[..., 2:4])
        return mu_t, self.theta[None] + torch.atan2(rot[..., 1], rot[..., 0])


def _log_linear(lr0: float, lr1: float, steps: int):
    """Learning rate decaying log-linearly from ``lr0`` to ``lr1`` over ``steps``, then held."""
    return lambda it: lr0 * (lr1 / lr0) ** min(1.0, it / max(1, steps))


def _optimizer(field: GP2DField, stage: int, I: int) -> tuple[torch.optim.Optimizer, list]:
    """Adam over the parameters stage ``stage`` trains, with the original's rates (module docstring)."""
    long, full = int(2 * I / 3), I
    gauss = [
        ([field.mu], _log_linear(1.6e-4, 1.6e-6, long)), ([field.color_raw, field.bg_raw], _log_linear(2.5e-3, 2.5e-3, 1)),
        ([field.opacity_raw], _log_linear(0.05, 0.05, 1)), ([field.log_scale], _log_linear(5e-3, 5e-3, 1)),
        ([field.theta], _log_linear(1e-3, 1e-3, 1)), ([field.feature], _log_linear(8e-4, 8e-5, long)),
    ]  # fmt: skip
    groups = [([*field.deform.parameters()], _log_linear(8e-4, 1.6e-6, long))]
    if stage != 2:
        groups += gauss
    if stage >= 2:
        groups += [([field.kp_pos], _log_linear(8e-4, 8e-5, full)), ([field.kp_feat], _log_linear(8e-4, 8e-5, long)),
                   ([*field.weight_net.parameters()], _log_linear(5e-3, 5e-5, full))]  # fmt: skip
    opt = torch.optim.Adam([{"params": p, "lr": f(0)} for p, f in groups], eps=1e-15)
    return opt, [f for _, f in groups]


def fit_field(frames: np.ndarray, cfg: GP2DConfig, seed: int = 0, log_every: int = 0) -> tuple[GP2DField, dict[str, Any]]:
    """Fit GP-2D's field to uint8 frames ``[T,H,W,3]`` (evenly spaced; normalised time ``t_i = i/(T-1)``).

    Schedule (fractions of ``I = cfg.iterations``): static warm-up to 1/60, stage 1 to 1/2, K-means, stage 2
    (Gaussians frozen) to 2/3, stage 3 to the end.

    Returns:
        ``(field, history)`` with ``loss`` (every 100 iterations), ``train_s``, ``config``.

    Raises:
        ValueError: with fewer than 2 frames or fewer key points than ``k_neighbours``.
    """
    if len(frames) < 2:
        raise ValueError(f"GP-2D needs at least 2 frames to fit, got {len(frames)}")
    T, H, W, _ = frames.shape
    cfg = cfg.resolved(H, W)
    torch.manual_seed(2024 * seed)
    gen = torch.Generator().manual_seed(2024 * seed)
    rng = np.random.default_rng(2024 * seed)
    x = torch.from_numpy(np.ascontiguousarray(frames)).permute(0, 3, 1, 2).float() / 255.0
    t_all = torch.linspace(0.0, 1.0, T)
    field = GP2DField(x[0], x.median(0).values, cfg, gen)
    I = cfg.iterations
    warm, s1, s2 = max(1, I // 60), I // 2, (2 * I) // 3
    noise_len = max(1, I // 6)
    stage, (opt, lrs) = 1, _optimizer(field, 1, I)
    hist: dict[str, Any] = {"loss": []}
    t0 = time.perf_counter()
    for it in range(I):
        if it == s1:
            field.init_keypoints(seed)
            stage, (opt, lrs) = 2, _optimizer(field, 2, I)
        elif it == s2:
            stage, (opt, lrs) = 3, _optimizer(field, 3, I)
        for g, f in zip(opt.param_groups, lrs):
            g["lr"] = f(it)
        b = torch.as_tensor(rng.choice(T, size=min(cfg.frames_per_step, T), replace=False))
        t = t_all[b]
        if stage == 1:
            noise = 0.1 * max(0.0, 1.0 - it / noise_len)
            mu_t, th_t = (field.mu[None].expand(len(b), -1, -1), field.theta[None].expand(len(b), -1)) if it < warm else field.deform_gaussians(t, noise)
        else:
            noise = 0.1 * max(0.0, 1.0 - (it - s1) / noise_len)
            mu_t, th_t = field.blend(field.keypoint_states(t, noise))
        pred = field.render(mu_t, th_t)
        loss = 0.8 * (pred - x[b]).abs().mean() + 0.2 * (1 - ssim(pred, x[b], win_size=11, sigma=1.5))
        if it >= warm:
            loss = loss + 1e-5 * field.feature.abs().mean()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        if it % 100 == 0 or it == I - 1:
            hist["loss"].append((it, float(loss.detach())))
            if log_every and it % log_every == 0:
                print(f"GP-2D field {it}/{I} (stage {stage}) loss {hist['loss'][-1][1]:.4f}", flush=True)
    hist.update(train_s=time.perf_counter() - t0, config=cfg.__dict__ | {"hidden": list(cfg.hidden)})
    return field.eval(), hist
