"""Compiled CPU kernels of the tile rasteriser (numba), forward and backward.

This is the CPU counterpart of a CUDA splatting kernel: primitives are binned
to ``tile x tile`` pixel tiles by a counting sort (stable, so ascending
primitive index is kept within each tile), then every tile is composited in
parallel, front to back; the backward pass walks each pixel's list back to
front, as gsplat does, and writes one gradient row per (tile, primitive) pair,
which torch then sums per primitive. The compositing rule is the one stated in
:mod:`lagsplat.render.rasterize`; :func:`lagsplat.render.rasterize.rasterize_dense`
is the reference it is tested against.

All arrays are float32 / int64 NumPy arrays; ``N = B * K`` flattened primitives.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

ALPHA_MIN = np.float32(1.0 / 255.0)
ALPHA_MAX = np.float32(0.99)


@njit(cache=True)
def bin_pairs(x0, x1, y0, y1, valid, K, n_tiles, ntx, tile):  # pragma: no cover - compiled
    """Counting sort of (tile, primitive) pairs.

    Args:
        x0, x1, y0, y1: int64 ``[N]`` inclusive pixel bounds of each primitive's support.
        valid: bool ``[N]``.
        K: primitives per image (``N = B K``).
        n_tiles, ntx: tiles per image and per row.
        tile: tile edge in pixels.

    Returns:
        ``(pairs int64 [P], key_start int64 [B n_tiles + 1])``: primitive index
        of each pair, grouped by key ``b * n_tiles + tile_id`` in ascending
        primitive order.
    """
    N = x0.shape[0]
    B = N // K
    n_keys = B * n_tiles
    counts = np.zeros(n_keys + 1, np.int64)
    for n in range(N):
        if not valid[n]:
            continue
        b = n // K
        for ty in range(y0[n] // tile, y1[n] // tile + 1):
            for tx in range(x0[n] // tile, x1[n] // tile + 1):
                counts[b * n_tiles + ty * ntx + tx + 1] += 1
    key_start = np.cumsum(counts)
    pos = key_start[:-1].copy()
    pairs = np.empty(key_start[-1], np.int64)
    for n in range(N):
        if not valid[n]:
            continue
        b = n // K
        for ty in range(y0[n] // tile, y1[n] // tile + 1):
            for tx in range(x0[n] // tile, x1[n] // tile + 1):
                key = b * n_tiles + ty * ntx + tx
                pairs[pos[key]] = n
                pos[key] += 1
    return pairs, key_start


@njit(parallel=True, cache=True, fastmath=False)
def forward_kernel(pairs, key_start, means, conic, opac, r2, colors, bg, H, W, tile, ntx, n_tiles, out, t_final, t_store):  # pragma: no cover
    """Front-to-back compositing of every tile; fills ``out [B,C,H,W]``,
    ``t_final [B,H,W]`` and the transmittance in front of each pair ``t_store [P, tile^2]``."""
    n_keys = key_start.shape[0] - 1
    C = colors.shape[1]
    for key in prange(n_keys):
        b = key // n_tiles
        tid = key - b * n_tiles
        ty = tid // ntx
        tx = tid - ty * ntx
        s = key_start[key]
        e = key_start[key + 1]
        acc = np.zeros(C, np.float32)
        for iy in range(tile):
            y = ty * tile + iy
            if y >= H:
                break
            py = np.float32(y + 0.5)
            for ix in range(tile):
                x = tx * tile + ix
                if x >= W:
                    break
                px = np.float32(x + 0.5)
                pix = iy * tile + ix
                T = np.float32(1.0)
                acc[:] = 0.0
                for p in range(s, e):
                    n = pairs[p]
                    t_store[p, pix] = T
                    dx = px - means[n, 0]
                    dy = py - means[n, 1]
                    d2 = conic[n, 0] * dx * dx + np.float32(2.0) * conic[n, 1] * dx * dy + conic[n, 2] * dy * dy
                    if d2 > r2[n]:
                        continue
                    a = opac[n] * math.exp(np.float32(-0.5) * d2)
                    if a > ALPHA_MAX:
                        a = ALPHA_MAX
                    if a < ALPHA_MIN:
                        continue
                    w = a * T
                    for c in range(C):
                        acc[c] += colors[n, c] * w
                    T = T * (np.float32(1.0) - a)
                for c in range(C):
                    out[b, c, y, x] = acc[c] + T * bg[c]
                t_final[b, y, x] = T


@njit(parallel=True, cache=True)
def render_kernel(pairs, key_start, means, conic, opac, r2, colors, bg, x0, x1, y0, y1, H, W, tile, ntx, n_tiles, out):  # pragma: no cover
    """Inference-only compositing (no gradients): fills ``out [B,C,H,W]``.

    The same rule and the same float32 arithmetic, pixel by pixel, as
    :func:`forward_kernel`, but the loops are swapped: per tile, primitives
    are visited front to back and each one touches only the pixels of its
    support box (``x0..x1``, ``y0..y1``, int64 ``[N]``, inclusive) inside the
    tile, with a per-pixel transmittance and colour accumulator. Nothing is
    stored for a backward pass. Used when no gradient is needed (the viewer,
    evaluation renders).
    """
    n_keys = key_start.shape[0] - 1
    C = colors.shape[1]
    for key in prange(n_keys):
        b = key // n_tiles
        tid = key - b * n_tiles
        ty = tid // ntx
        tx = tid - ty * ntx
        s = key_start[key]
        e = key_start[key + 1]
        T = np.ones((tile, tile), np.float32)
        acc = np.zeros((tile, tile, C), np.float32)
        ox, oy = tx * tile, ty * tile
        for p in range(s, e):
            n = pairs[p]
            ya = max(y0[n], oy)
            yb = min(y1[n], oy + tile - 1, H - 1)
            xa = max(x0[n], ox)
            xb = min(x1[n], ox + tile - 1, W - 1)
            for y in range(ya, yb + 1):
                dy = np.float32(y + 0.5) - means[n, 1]
                for x in range(xa, xb + 1):
                    dx = np.float32(x + 0.5) - means[n, 0]
                    d2 = conic[n, 0] * dx * dx + np.float32(2.0) * conic[n, 1] * dx * dy + conic[n, 2] * dy * dy
                    if d2 > r2[n]:
                        continue
                    a = opac[n] * math.exp(np.float32(-0.5) * d2)
                    if a > ALPHA_MAX:
                        a = ALPHA_MAX
                    if a < ALPHA_MIN:
                        continue
                    iy, ix = y - oy, x - ox
                    w = a * T[iy, ix]
                    for c in range(C):
                        acc[iy, ix, c] += colors[n, c] * w
                    T[iy, ix] = T[iy, ix] * (np.float32(1.0) - a)
        for iy in range(tile):
            y = oy + iy
            if y >= H:
                break
            for ix in range(tile):
                x = ox + ix
                if x >= W:
                    break
                for c in range(C):
                    out[b, c, y, x] = acc[iy, ix, c] + T[iy, ix] * bg[c]


@njit(parallel=True, cache=True, fastmath=False)
def backward_kernel(pairs, key_start, means, conic, opac, r2, colors, bg, H, W, tile, ntx, n_tiles, grad_out, t_final, t_store, g_pair):  # pragma: no cover
    """Back-to-front gradients. ``g_pair [P, 6 + C]`` receives, per pair,
    d/d(mean x, mean y, conic a, conic b, conic c, opacity, colour...)."""
    n_keys = key_start.shape[0] - 1
    C = colors.shape[1]
    for key in prange(n_keys):
        b = key // n_tiles
        tid = key - b * n_tiles
        ty = tid // ntx
        tx = tid - ty * ntx
        s = key_start[key]
        e = key_start[key + 1]
        S = np.zeros(C, np.float32)
        for iy in range(tile):
            y = ty * tile + iy
            if y >= H:
                break
            py = np.float32(y + 0.5)
            for ix in range(tile):
                x = tx * tile + ix
                if x >= W:
                    break
                px = np.float32(x + 0.5)
                pix = iy * tile + ix
                Tf = t_final[b, y, x]
                for c in range(C):
                    S[c] = Tf * bg[c]
                for p in range(e - 1, s - 1, -1):
                    n = pairs[p]
                    dx = px - means[n, 0]
                    dy = py - means[n, 1]
                    ca = conic[n, 0]
                    cb = conic[n, 1]
                    cc = conic[n, 2]
                    d2 = ca * dx * dx + np.float32(2.0) * cb * dx * dy + cc * dy * dy
                    if d2 > r2[n]:
                        continue
                    g = math.exp(np.float32(-0.5) * d2)
                    a = opac[n] * g
                    clamped = a > ALPHA_MAX
                    if clamped:
                        a = ALPHA_MAX
                    if a < ALPHA_MIN:
                        continue
                    T = t_store[p, pix]
                    w = a * T
                    gc = np.float32(0.0)
                    gs = np.float32(0.0)
                    for c in range(C):
                        go = grad_out[b, c, y, x]
                        g_pair[p, 6 + c] += go * w
                        gc += go * colors[n, c]
                        gs += go * S[c]
                        S[c] += colors[n, c] * w
                    if clamped:
                        continue
                    d_alpha = T * gc - gs / (np.float32(1.0) - a)
                    g_pair[p, 5] += d_alpha * g
                    d_d2 = d_alpha * np.float32(-0.5) * a
                    g_pair[p, 0] += d_d2 * np.float32(-2.0) * (ca * dx + cb * dy)
                    g_pair[p, 1] += d_d2 * np.float32(-2.0) * (cb * dx + cc * dy)
                    g_pair[p, 2] += d_d2 * dx * dx
                    g_pair[p, 3] += d_d2 * np.float32(2.0) * dx * dy
                    g_pair[p, 4] += d_d2 * dy * dy
