"""Differentiable 2D Gaussian rasterisation and the backend switch.

Every backend renders the compositing rule of :mod:`lagsplat.render.rule`; the
compiled CPU backend is :mod:`lagsplat.render.rasterize_cpu`, gsplat's CUDA
kernels :mod:`lagsplat.render.rasterize_gsplat`.

Culling
-------
A Gaussian only touches pixels where ``a_kp >= 1/255``, i.e. where
``d2 <= r2 = min(9, 2 ln(255 o_k))``. The axis-aligned extent of that ellipse is
``r sqrt(Sigma'_xx)`` by ``r sqrt(Sigma'_yy)``; :func:`rasterize_tiles` lists the
``tile x tile`` pixel tiles each extent overlaps, sorts the (tile, primitive)
pairs by tile (stable, so index order survives) and composites every pair on its
tile's pixels. Transmittance is an exclusive segmented cumulative sum of
``log(1 - a)`` (accumulated in float64). Cost is proportional to the number of
(tile, primitive) pairs, not to ``K H W``. :func:`rasterize_dense` evaluates the
same rule on all ``K x H x W`` pairs; it is the test reference.
"""

from __future__ import annotations

import math
from typing import Literal

import torch
from torch import Tensor

from lagsplat.render.rasterize_cpu import numba_available, rasterize_cpu
from lagsplat.render.rasterize_gsplat import gsplat_available, rasterize_gsplat
from lagsplat.render.rule import EPS2D, alpha_of, pixel_bounds, prepare_gaussians

__all__ = ["rasterize", "rasterize_tiles", "rasterize_dense", "Backend"]

Backend = Literal["auto", "cpu", "torch", "dense", "gsplat"]


def rasterize_dense(
    means: Tensor,
    covs: Tensor,
    opacities: Tensor,
    colors: Tensor,
    height: int,
    width: int,
    background: Tensor | None = None,
    eps2d: float = EPS2D,
) -> Tensor:
    """Reference rasteriser: the compositing rule on every (primitive, pixel) pair.

    Memory and time are ``O(B K H W)``; use it for tests and small images only.

    Args:
        means: ``[B,K,2]`` centres in pixels (x right, y down; pixel centres at ``+0.5``).
        covs: ``[K,2,2]`` or ``[B,K,2,2]`` covariances in pixels^2.
        opacities: ``[B,K]`` opacities in [0, 1].
        colors: ``[K,C]`` or ``[B,K,C]`` colours.
        height, width: output size in pixels.
        background: ``[C]`` colour behind everything (default black).
        eps2d: dilation added to each covariance, pixels^2.

    Returns:
        ``[B,C,H,W]`` image.

    Raises:
        ValueError: on inconsistent shapes.
    """
    B, K, conic, colors, r2, _, _ = prepare_gaussians(means, covs, opacities, colors, eps2d)
    dev, dt = means.device, means.dtype
    ys = torch.arange(height, device=dev, dtype=dt) + 0.5
    xs = torch.arange(width, device=dev, dtype=dt) + 0.5
    dx = xs.view(1, 1, 1, width) - means[..., 0].view(B, K, 1, 1)
    dy = ys.view(1, 1, height, 1) - means[..., 1].view(B, K, 1, 1)
    a, b, c = (conic[..., i].view(B, K, 1, 1) for i in range(3))
    d2 = a * dx * dx + 2.0 * b * dx * dy + c * dy * dy
    alpha = alpha_of(d2, opacities.view(B, K, 1, 1), r2.view(B, K, 1, 1))  # [B,K,H,W]
    log1m = torch.log1p(-alpha).double()
    cs = torch.cumsum(log1m, dim=1)
    trans = torch.exp(cs - log1m).to(dt)  # exclusive product over j < k
    w = trans * alpha
    img = torch.einsum("bkhw,bkc->bchw", w, colors)
    if background is not None:
        t_final = torch.exp(cs[:, -1]).to(dt)  # [B,H,W]
        img = img + t_final.unsqueeze(1) * background.view(1, -1, 1, 1).to(dt)
    return img


def rasterize_tiles(
    means: Tensor,
    covs: Tensor,
    opacities: Tensor,
    colors: Tensor,
    height: int,
    width: int,
    background: Tensor | None = None,
    eps2d: float = EPS2D,
    tile: int = 8,
) -> Tensor:
    """Tile-culled rasteriser; same image as :func:`rasterize_dense`, differentiable.

    Gradients flow to ``means``, ``covs``, ``opacities`` and ``colors``.
    Arguments and return value as :func:`rasterize_dense`, plus ``tile``, the
    edge of the square pixel tiles used for culling.
    """
    B, K, conic, colors, r2, sxx, syy = prepare_gaussians(means, covs, opacities, colors, eps2d)
    dev, dt = means.device, means.dtype
    C = colors.shape[-1]
    ntx, nty = math.ceil(width / tile), math.ceil(height / tile)
    n_tiles = ntx * nty

    with torch.no_grad():
        x0, x1, y0, y1, valid = pixel_bounds(means, r2, sxx, syy, height, width)
        tx0 = torch.div(x0, tile, rounding_mode="floor")
        tx1 = torch.div(x1, tile, rounding_mode="floor")
        ty0 = torch.div(y0, tile, rounding_mode="floor")
        ty1 = torch.div(y1, tile, rounding_mode="floor")
        nwx = (tx1 - tx0 + 1).clamp_min(0)
        counts = torch.where(valid, nwx * (ty1 - ty0 + 1).clamp_min(0), torch.zeros_like(nwx)).reshape(-1)
        n_pairs = int(counts.sum())
        flat = torch.repeat_interleave(torch.arange(B * K, device=dev), counts)  # (b,k) per pair
        offsets = torch.cumsum(counts, 0) - counts
        local = torch.arange(n_pairs, device=dev) - offsets[flat]
        w_flat = nwx.reshape(-1)[flat]
        tx = tx0.reshape(-1)[flat] + local % w_flat
        ty = ty0.reshape(-1)[flat] + torch.div(local, w_flat, rounding_mode="floor")
        bidx = torch.div(flat, K, rounding_mode="floor")
        key = bidx * n_tiles + ty * ntx + tx
        key, order = torch.sort(key, stable=True)
        flat, tx, ty = flat[order], tx[order], ty[order]
        seg_keys, seg_counts = torch.unique_consecutive(key, return_counts=True)
        seg_start = torch.cumsum(seg_counts, 0) - seg_counts
        pair_start = torch.repeat_interleave(seg_start, seg_counts)
        lin = torch.arange(tile, device=dev, dtype=dt) + 0.5
        px = (tx * tile).to(dt).unsqueeze(1) + lin.unsqueeze(0)  # [P, t]
        py = (ty * tile).to(dt).unsqueeze(1) + lin.unsqueeze(0)

    mu = means.reshape(B * K, 2)[flat]  # [P,2]
    cn = conic.reshape(B * K, 3)[flat]  # [P,3]
    op = opacities.reshape(B * K)[flat]
    dx = (px - mu[:, :1]).unsqueeze(1)  # [P,1,t]  (columns)
    dy = (py - mu[:, 1:]).unsqueeze(2)  # [P,t,1]  (rows)
    d2 = cn[:, 0, None, None] * dx * dx + 2.0 * cn[:, 1, None, None] * dx * dy + cn[:, 2, None, None] * dy * dy
    alpha = alpha_of(d2, op[:, None, None], r2.reshape(-1)[flat][:, None, None]).reshape(n_pairs, tile * tile)
    log1m = torch.log1p(-alpha)
    cs = torch.cumsum(log1m.double(), dim=0)
    excl = cs - log1m.double()
    trans = torch.exp(excl - excl[pair_start]).to(dt)
    wgt = trans * alpha  # [P, t*t]
    col = colors.reshape(B * K, C)[flat]  # [P,C]
    out = torch.zeros(B * n_tiles, tile * tile, C, device=dev, dtype=dt)
    out = out.index_add(0, key, wgt.unsqueeze(-1) * col.unsqueeze(1))
    if background is not None:
        logt = torch.zeros(B * n_tiles, tile * tile, device=dev, dtype=dt).index_add(0, key, log1m)
        out = out + torch.exp(logt).unsqueeze(-1) * background.to(dt).view(1, 1, C)
    img = out.view(B, nty, ntx, tile, tile, C).permute(0, 5, 1, 3, 2, 4).reshape(B, C, nty * tile, ntx * tile)
    return img[:, :, :height, :width]


def rasterize(
    means: Tensor,
    covs: Tensor,
    opacities: Tensor,
    colors: Tensor,
    height: int,
    width: int,
    background: Tensor | None = None,
    backend: Backend = "auto",
    eps2d: float = EPS2D,
    tile: int = 8,
) -> Tensor:
    """Render 2D Gaussians with the compositing rule of this module.

    Args:
        means: ``[B,K,2]`` centres in pixels.
        covs: ``[K,2,2]`` or ``[B,K,2,2]`` covariances in pixels^2.
        opacities: ``[B,K]`` in [0, 1].
        colors: ``[K,C]`` or ``[B,K,C]``.
        height, width: output size in pixels.
        background: ``[C]`` colour (default black).
        backend: ``"cpu"`` (compiled tile kernels, the default on CPU),
            ``"torch"`` (tile-culled in pure torch, any device, supports
            double backward and forward-mode AD), ``"dense"`` (reference),
            ``"gsplat"`` (gsplat's CUDA kernels, :func:`rasterize_gsplat`) or
            ``"auto"`` (``"cpu"`` for CPU tensors when numba is importable,
            ``"gsplat"`` for CUDA tensors when gsplat is installed, else ``"torch"``).
        eps2d: covariance dilation in pixels^2.
        tile: culling tile edge in pixels (torch backend; the compiled CPU
            kernels use 16 x 16 tiles, gsplat its own).

    Returns:
        ``[B,C,H,W]`` image.

    Raises:
        ValueError: on inconsistent shapes or an unknown backend.
        RuntimeError: if ``"gsplat"`` is asked for without gsplat or CUDA tensors.
    """
    if backend == "auto":
        if means.device.type == "cpu":
            backend = "cpu" if numba_available() else "torch"
        else:
            backend = "gsplat" if means.device.type == "cuda" and gsplat_available() else "torch"
    if backend == "cpu":
        return rasterize_cpu(means, covs, opacities, colors, height, width, background, eps2d)
    if backend == "torch":
        return rasterize_tiles(means, covs, opacities, colors, height, width, background, eps2d, tile)
    if backend == "dense":
        return rasterize_dense(means, covs, opacities, colors, height, width, background, eps2d)
    if backend == "gsplat":
        return rasterize_gsplat(means, covs, opacities, colors, height, width, background, eps2d)
    raise ValueError(f"unknown rasterizer backend {backend!r}; expected auto, torch, dense or gsplat")
