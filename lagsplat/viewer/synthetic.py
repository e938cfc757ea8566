"""A hand-built system for the viewer's tests and benchmarks: no video, no training.

A pendulum (rod and bob) in front of a static tiled background, as a
:class:`~lagsplat.models.decoder.ConditionedGaussians` whose parameters are set
directly: the latent ``q`` (d = 1, the chart is the identity) is the swing
angle in radians, each rod / bob primitive at offset ``(dx, dy)`` from the
pivot moves with the rigid-rotation Jacobian ``J = (dy, -dx)`` px/rad (the
decoder's means are affine in ``q``, so this is the small-angle pendulum), the
background primitives have ``J = 0``. The Lagrangian is untrained with its
energy scales set to a natural frequency ``f_hz`` and floor damping ratio
``zeta`` (:meth:`~lagsplat.models.lagrangian.Lagrangian.init_energy_scales`).

Nothing here is used by the pipeline.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import torch

from lagsplat.chart import Chart
from lagsplat.models.decoder import DIAG_FLOOR, ConditionedGaussians, inverse_softplus
from lagsplat.models.lagrangian import Lagrangian

__all__ = ["decoder_from_primitives", "synthetic_pendulum"]


@torch.no_grad()
def decoder_from_primitives(pos_px, J_px, colors, alpha, sigma_px, height: int, width: int, gate_std: float = 10.0) -> ConditionedGaussians:
    """A :class:`ConditionedGaussians` (d = 1) with the given rendered geometry at ``q = 0``.

    Args:
        pos_px: ``[K,2]`` positions at ``q = 0``, px.
        J_px: ``[K,2]`` Jacobians ``d mu / d q``, px per unit ``q``.
        colors: ``[K,3]`` RGB in (0, 1).
        alpha: ``[K]`` opacities in (0, 1).
        sigma_px: ``[K]`` isotropic spatial std, px.
        height, width: image size the pixel units refer to.
        gate_std: latent std of every primitive (a wide gate: always visible for ``|q| << gate_std``).
    """
    pos = torch.as_tensor(pos_px, dtype=torch.float32)
    K = len(pos)
    scale = torch.tensor([float(width), float(height)])
    dec = ConditionedGaussians(K, 1)
    n = 3
    L = torch.zeros(K, n, n)
    L[:, 0, 0] = gate_std
    L[:, 1:, 0] = torch.as_tensor(J_px, dtype=torch.float32) / scale * gate_std  # J = L_sq / L_qq
    sig = torch.as_tensor(sigma_px, dtype=torch.float32)
    L[:, 1, 1] = sig / width
    L[:, 2, 2] = sig / height
    raw = L[:, dec.tril_i, dec.tril_j]
    diag = dec.tril_i == dec.tril_j
    raw[:, diag] = inverse_softplus(raw[:, diag] - DIAG_FLOOR)
    dec.L_raw.copy_(raw)
    dec.mu_raw.copy_(torch.logit(((pos / scale + 0.1) / 1.2).clamp(1e-4, 1 - 1e-4)))
    dec.mu_q.zero_()
    dec.logit_alpha.copy_(torch.logit(torch.as_tensor(alpha, dtype=torch.float32).clamp(1e-4, 1 - 1e-4)))
    dec.logit_color.copy_(torch.logit(torch.as_tensor(colors, dtype=torch.float32).clamp(1e-3, 1 - 1e-3)))
    return dec.eval()


def synthetic_pendulum(size: int = 64, f_hz: float = 0.8, zeta: float = 0.02, fps: float = 30.0, seconds: float = 10.0, n_background: int = 12, seed: int = 0):
    """``(ae, chart, model)`` of a pendulum rendered at ``size x size`` px.

    Args:
        size: image side, px.
        f_hz, zeta: natural frequency (Hz) and floor damping ratio of the Lagrangian.
        fps, seconds: the chart's timestamps (``dt = 1 / fps``) and length; its
            ``q`` is a damped swing from 0.3 rad, the last 40 % held out.
        n_background: background tiles per side (``n_background**2`` static primitives).
        seed: RNG seed of the background colours.

    Returns:
        ``ae`` (``decoder``, ``height``, ``width``, ``decode(z, height, width)``),
        a :class:`~lagsplat.chart.Chart` (identity whitening) and the
        :class:`~lagsplat.models.lagrangian.Lagrangian` (eval mode, rest at ``q = 0``).
    """
    rng = np.random.default_rng(seed)
    s = size / 64.0
    pivot = np.array([32.0, 8.0]) * s
    length = 36.0 * s
    pos, J, col, alpha, sig = [], [], [], [], []

    def add(p, c, a, sg, moving):
        dx, dy = p[0] - pivot[0], p[1] - pivot[1]
        pos.append(p)
        J.append([dy, -dx] if moving else [0.0, 0.0])
        col.append(c)
        alpha.append(a)
        sig.append(sg)

    for r in np.linspace(0.0, length, 16):  # rod
        add(pivot + [0.0, r], [0.15, 0.15, 0.15], 0.95, 1.0 * s, True)
    for a in np.linspace(0, 2 * np.pi, 24, endpoint=False):  # bob: red left half, blue right half
        for rr in (2.5 * s, 5.0 * s):
            p = pivot + [0.0, length] + rr * np.array([math.cos(a), math.sin(a)])
            add(p, [0.85, 0.15, 0.15] if math.cos(a) < 0 else [0.15, 0.25, 0.9], 0.95, 1.6 * s, True)
    add(pivot + [0.0, length], [0.5, 0.2, 0.5], 0.95, 2.0 * s, True)
    tile = size / n_background
    for i in range(n_background):  # background: static tiles, last in the list: behind (primitives composite in index order, front first)
        for j in range(n_background):
            g = 0.8 + 0.1 * ((i + j) % 2) + 0.03 * rng.standard_normal()
            add([(j + 0.5) * tile, (i + 0.5) * tile], [g, g, g + 0.02], 0.99, 0.6 * tile, False)
    dec = decoder_from_primitives(np.array(pos), np.array(J), np.array(col), np.array(alpha), np.array(sig), size, size)

    def decode(z, height=None, width=None):
        return dec(z, height or size, width or size)

    ae = SimpleNamespace(decoder=dec, height=size, width=size, decode=decode)

    torch.manual_seed(seed)
    model = Lagrangian(1, hidden=(16, 16), learn_rest=False)
    model.init_energy_scales(2 * math.pi * f_hz, zeta)
    model.eval()

    n = round(seconds * fps)
    t = np.arange(n) / fps
    w = 2 * math.pi * f_hz
    q = (0.3 * np.exp(-zeta * w * t) * np.cos(w * t))[:, None]
    split = (np.arange(n) >= int(0.6 * n)).astype(np.int8)
    eye = np.eye(1)
    chart = Chart(
        mean=np.zeros(1), W=eye, W_inv=eye, q=q, t=t, split=split, G_bar=eye, A=eye,
        ae_mse=np.zeros(n), ae_floor_train=0.0, ae_floor_held_out=0.0, height=size, width=size,
        meta={"synthetic": "lagsplat.viewer.synthetic.synthetic_pendulum"},
    )
    return ae, chart, model
