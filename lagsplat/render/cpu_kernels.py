"""Compiled CPU kernels of the tile rasteriser (numba), forward and backward.

This is the CPU counterpart of a CUDA splatting kernel. Primitives are binned
to ``TILE x TILE`` pixel tiles by a counting sort (stable, so ascending
primitive index is kept within each tile); every tile is then composited in
parallel, front to back. Within a tile, each (tile, primitive) pair is one
straight loop over the tile rows its support box covers, flattened
(``i = row * TILE + column``), so that LLVM vectorises it: ``TILE = 16`` is
one AVX-512 register of float32, every per-pixel quantity lives in a
tile-local array, the exponential is a branch-free polynomial
(:data:`exp_neg`, in the form that vectorises on the target CPU), and the cut, cap and support tests are selects, not
branches.

The backward pass replays the forward loop front to back with the same
arithmetic, so it needs no per-pair transmittance store: each pair reads the
transmittance in front of it as the forward pass computed it. The colour
behind a primitive, which the opacity gradient needs, is carried as one
scalar per pixel, ``Gb = sum_c grad_c * (out_c - acc_c)`` (the forward image
minus what has been composited so far, weighted by the upstream gradient),
updated by ``Gb -= w * sum_c grad_c colour_c`` after each primitive. Each
pair's gradient is reduced over its pixels in registers and written once; a
second parallel pass (:func:`sum_pairs`) sums the pairs of each primitive.

The compositing rule is the one stated in :mod:`lagsplat.render.rule`;
:func:`lagsplat.render.rasterize.rasterize_dense` is the reference it is
tested against. All arrays are float32 / int64 NumPy arrays; ``N = B * K``
flattened primitives.
"""

from __future__ import annotations

import os

import numpy as np
from numba import njit, prange

ALPHA_MIN = np.float32(1.0 / 255.0)
ALPHA_MAX = np.float32(0.99)
TILE = 16  # tile edge in pixels; the kernels assume it (flat index: row = i >> 4, column = i & 15)
_NPIX = TILE * TILE
_LN2_HI = np.float32(0.693359375)  # ln 2 split in two (Cody-Waite), the high part exact in float32
_LN2_LO = np.float32(-2.12194440e-4)
_LOG2E = np.float32(1.4426950408889634)
_F0 = np.float32(0.0)
_F1 = np.float32(1.0)


@njit(inline="always")
def tile_origin(key, n_tiles, ntx, W):  # pragma: no cover - compiled
    """The image ``b``, the tile's top-left pixel ``(ox, oy)`` and its width ``xlim`` inside the image (a tile
    cut by the right edge is narrower) of a (image, tile) sort ``key``, the tiles of a row of ``ntx`` numbered
    row by row, ``n_tiles`` per image."""
    b = key // n_tiles
    tid = key - b * n_tiles
    ty = tid // ntx
    tx = tid - ty * ntx
    ox, oy = tx * TILE, ty * TILE
    return b, ox, oy, min(TILE, W - ox)


@njit(inline="always", error_model="numpy")
def exp_neg_shift(x):  # pragma: no cover - compiled
    """``exp(x)`` in float32 for ``x`` in ``[-4.5, 0]`` (the Gaussian falloff ``-d2/2`` inside the 3-sigma cut).

    Branch-free so that the pixel loops vectorise: ``x = k ln2 + r`` with integer ``k`` in
    ``[-7, 0]`` and ``|r| <= 0.35`` (ln 2 split in two so the reduction is exact), ``exp(r)`` by
    :func:`_taylor7`, and ``2^k`` from an integer shift: the form for AVX-512 targets, whose
    packed float-to-int64 conversion keeps the loop vectorised (the one the kernels were tuned with).
    Relative error at most 1.2e-7 (one float32 ulp), the same bits as :func:`exp_neg_select`
    (``tests/test_render.py``). Inputs below -4.5 are clamped to it (their alphas are cut anyway).
    """
    x = max(x, np.float32(-4.5))
    k = int(x * _LOG2E - np.float32(0.5))  # truncation toward zero = round to nearest for x <= 0
    kf = np.float32(k)
    r = (x - kf * _LN2_HI) - kf * _LN2_LO
    p = _taylor7(r)
    return p * (np.float32(1 << (k + 8)) * np.float32(1.0 / 256.0))


@njit(inline="always", error_model="numpy")
def exp_neg_select(x):  # pragma: no cover - compiled
    """``exp(x)`` in float32 for ``x`` in ``[-4.5, 0]`` (the Gaussian falloff ``-d2/2`` inside the 3-sigma cut).

    Branch-free so that the pixel loops vectorise: ``x = k ln2 + r`` with integer ``k`` in
    ``[-7, 0]`` and ``|r| <= 0.35`` (ln 2 split in two so the reduction is exact), ``exp(r)`` by
    :func:`_taylor7`, and ``2^k`` by three selects of exact powers of two, all in float32: the
    form for targets without AVX-512 (AVX2), where the float-to-integer conversion of
    :func:`exp_neg_shift` is scalar and keeps the loop scalar. Same bits and error as
    :func:`exp_neg_shift`; inputs below -4.5 are clamped to it.
    """
    x = max(x, np.float32(-4.5))
    kf = np.ceil(x * _LOG2E - np.float32(0.5))  # = round to nearest for x <= 0 (a truncation toward zero)
    r = (x - kf * _LN2_HI) - kf * _LN2_LO
    p = _taylor7(r)
    m = -kf  # 0 .. 7: 2^k = 2^-m, its binary digits as selects
    s = np.float32(1.0 / 16.0) if m >= np.float32(4.0) else _F1
    m = m - np.float32(4.0) if m >= np.float32(4.0) else m
    s = s * np.float32(0.25) if m >= np.float32(2.0) else s
    m = m - np.float32(2.0) if m >= np.float32(2.0) else m
    s = s * np.float32(0.5) if m >= np.float32(1.0) else s
    return p * s


@njit(inline="always", error_model="numpy")
def _taylor7(r):  # pragma: no cover - compiled
    """``exp(r)`` for ``|r| <= 0.35``: its Taylor polynomial to degree 7 (Horner, float32)."""
    p = np.float32(1.0 / 5040.0)
    p = p * r + np.float32(1.0 / 720.0)
    p = p * r + np.float32(1.0 / 120.0)
    p = p * r + np.float32(1.0 / 24.0)
    p = p * r + np.float32(1.0 / 6.0)
    p = p * r + np.float32(0.5)
    p = p * r + _F1
    return p * r + _F1


def _targets_avx512() -> bool:
    """Whether numba compiles for a CPU with AVX-512: ``NUMBA_CPU_FEATURES`` when set (a chosen target), else the host's."""
    feats = os.environ.get("NUMBA_CPU_FEATURES")
    if feats is None:
        try:
            import llvmlite.binding as llvm

            feats = llvm.get_host_cpu_features().flatten()
        except (ImportError, RuntimeError):
            return False
    return "+avx512f" in feats.split(",")


#: The exponential the kernels use, chosen by the target's vector extension (:func:`_targets_avx512`).
exp_neg = exp_neg_shift if _targets_avx512() else exp_neg_select


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


@njit(parallel=True, cache=True, error_model="numpy")
def forward_kernel(pairs, key_start, means, conic, opac, r2, colors, bg, x0, x1, y0, y1, H, W, ntx, n_tiles, out):  # pragma: no cover
    """Front-to-back compositing of every tile; fills ``out [B,C,H,W]``.

    Per tile, primitives are visited front to back (ascending index); each
    covers the rows ``y0..y1`` (int64 ``[N]``, inclusive) of its support box
    inside the tile, every column of them, its alpha set to 0 where the
    rule's cut or support test fails or the column is off the image.
    Nothing per pair is stored: :func:`backward_kernel` replays this loop.
    """
    n_keys = key_start.shape[0] - 1
    C = colors.shape[1]
    for key in prange(n_keys):
        b, ox, oy, xlim = tile_origin(key, n_tiles, ntx, W)
        T = np.ones(_NPIX, np.float32)
        w_r = np.empty(_NPIX, np.float32)
        acc = np.zeros((C, _NPIX), np.float32)
        for p in range(key_start[key], key_start[key + 1]):
            n = pairs[p]
            row0 = max(y0[n], oy) - oy
            i0, i1 = row0 * TILE, (min(y1[n], oy + TILE - 1, H - 1) - oy + 1) * TILE
            # views, so the loop index starts at 0 and LLVM can bound the accesses
            Tv, wv = T[i0:i1], w_r[i0:i1]
            fx0 = np.float32(ox + 0.5) - means[n, 0]
            fy0 = np.float32(oy + row0 + 0.5) - means[n, 1]
            ca, cb, cc = conic[n, 0], conic[n, 1], conic[n, 2]
            o, rr = opac[n], r2[n]
            for i in range(i1 - i0):
                ix = i & (TILE - 1)
                dx = fx0 + np.float32(ix)
                dy = fy0 + np.float32(i >> 4)
                d2 = ca * dx * dx + np.float32(2.0) * cb * dx * dy + cc * dy * dy
                a = min(o * exp_neg(np.float32(-0.5) * d2), ALPHA_MAX)
                a = a if (d2 <= rr and a >= ALPHA_MIN and ix < xlim) else _F0
                t = Tv[i]
                wv[i] = a * t
                Tv[i] = t * (_F1 - a)
            for c in range(C):
                col = colors[n, c]
                av = acc[c, i0:i1]
                for i in range(i1 - i0):
                    av[i] += col * wv[i]
        for iy in range(min(TILE, H - oy)):
            for ix in range(xlim):
                i = iy * TILE + ix
                for c in range(C):
                    out[b, c, oy + iy, ox + ix] = acc[c, i] + T[i] * bg[c]


@njit(parallel=True, cache=True, fastmath={"reassoc", "nsz", "arcp"}, error_model="numpy")
def backward_kernel(pairs, key_start, means, conic, opac, r2, colors, y0, y1, H, W, ntx, n_tiles, out, grad_out, g_pair):  # pragma: no cover
    """Gradients of ``sum(grad_out * out)`` per (tile, primitive) pair.

    Replays :func:`forward_kernel` front to back (see the module docstring);
    ``g_pair [P, 6 + C]`` receives, per pair, d/d(mean x, mean y, conic a,
    conic b, conic c, opacity, colour...) summed over the pair's pixels.
    Reassociation is allowed so that these sums vectorise (the order of the
    additions within a pair is the vector unit's, fixed for a machine).

    Args:
        out: ``[B,C,H,W]`` the image :func:`forward_kernel` returned.
        grad_out: ``[B,C,H,W]`` upstream gradient.
    """
    n_keys = key_start.shape[0] - 1
    C = colors.shape[1]
    for key in prange(n_keys):
        b, ox, oy, xlim = tile_origin(key, n_tiles, ntx, W)
        T = np.ones(_NPIX, np.float32)
        Gb = np.zeros(_NPIX, np.float32)  # sum_c grad_c * (colour behind the next primitive)_c
        w_r = np.empty(_NPIX, np.float32)
        gc_r = np.empty(_NPIX, np.float32)
        go = np.zeros((C, _NPIX), np.float32)
        for c in range(C):
            for iy in range(min(TILE, H - oy)):
                for ix in range(xlim):
                    gv = grad_out[b, c, oy + iy, ox + ix]
                    go[c, iy * TILE + ix] = gv
                    Gb[iy * TILE + ix] += gv * out[b, c, oy + iy, ox + ix]
        for p in range(key_start[key], key_start[key + 1]):
            n = pairs[p]
            row0 = max(y0[n], oy) - oy
            i0, i1 = row0 * TILE, (min(y1[n], oy + TILE - 1, H - 1) - oy + 1) * TILE
            m = i1 - i0
            Tv, Gv, wv, gcv = T[i0:i1], Gb[i0:i1], w_r[i0:i1], gc_r[i0:i1]
            fx0 = np.float32(ox + 0.5) - means[n, 0]
            fy0 = np.float32(oy + row0 + 0.5) - means[n, 1]
            ca, cb, cc = conic[n, 0], conic[n, 1], conic[n, 2]
            o, rr = opac[n], r2[n]
            # gc = sum_c grad_c colour_c, per pixel
            g0, col0 = go[0, i0:i1], colors[n, 0]
            for i in range(m):
                gcv[i] = g0[i] * col0
            for c in range(1, C):
                gcc, col = go[c, i0:i1], colors[n, c]
                for i in range(m):
                    gcv[i] += gcc[i] * col
            g_mx = g_my = g_ca = g_cb = g_cc = g_o = _F0
            for i in range(m):
                ix = i & (TILE - 1)
                dx = fx0 + np.float32(ix)
                dy = fy0 + np.float32(i >> 4)
                d2 = ca * dx * dx + np.float32(2.0) * cb * dx * dy + cc * dy * dy
                g = exp_neg(np.float32(-0.5) * d2)
                a_raw = o * g
                a = min(a_raw, ALPHA_MAX)
                ok = d2 <= rr and a >= ALPHA_MIN and ix < xlim
                a = a if ok else _F0
                t = Tv[i]
                w = a * t
                wv[i] = w
                gc = gcv[i]
                gs = Gv[i] - w * gc  # grad . (colour behind this primitive)
                Gv[i] = gs
                one_m = _F1 - a
                Tv[i] = t * one_m
                # d out / d alpha = colour T - behind / (1 - alpha); no alpha gradient where capped
                d_alpha = t * gc - gs / one_m
                d_alpha = d_alpha if (ok and a_raw <= ALPHA_MAX) else _F0
                g_o += d_alpha * g
                d_d2 = d_alpha * np.float32(-0.5) * a
                g_mx += d_d2 * np.float32(-2.0) * (ca * dx + cb * dy)
                g_my += d_d2 * np.float32(-2.0) * (cb * dx + cc * dy)
                g_ca += d_d2 * dx * dx
                g_cb += d_d2 * np.float32(2.0) * dx * dy
                g_cc += d_d2 * dy * dy
            g_pair[p, 0] = g_mx
            g_pair[p, 1] = g_my
            g_pair[p, 2] = g_ca
            g_pair[p, 3] = g_cb
            g_pair[p, 4] = g_cc
            g_pair[p, 5] = g_o
            for c in range(C):  # in float64: a product of two float32 is exact there, so the sum does not depend on
                gcc = go[c, i0:i1]  # how the compiler fuses or vectorises it (fresh and cached kernels agree)
                sc = 0.0
                for i in range(m):
                    sc += np.float64(gcc[i]) * np.float64(wv[i])
                g_pair[p, 6 + c] = np.float32(sc)


@njit(cache=True)
def group_by_primitive(pairs, N):  # pragma: no cover - compiled
    """Counting sort of the pair list by primitive.

    Args:
        pairs: int64 ``[P]`` primitive index of each (tile, primitive) pair.
        N: number of primitives.

    Returns:
        ``(slots int64 [P], prim_start int64 [N + 1])``: the pairs of
        primitive ``n`` are ``slots[prim_start[n]:prim_start[n + 1]]``, in
        ascending pair order.
    """
    counts = np.zeros(N + 1, np.int64)
    for p in range(pairs.shape[0]):
        counts[pairs[p] + 1] += 1
    prim_start = np.cumsum(counts)
    pos = prim_start[:-1].copy()
    slots = np.empty(pairs.shape[0], np.int64)
    for p in range(pairs.shape[0]):
        n = pairs[p]
        slots[pos[n]] = p
        pos[n] += 1
    return slots, prim_start


@njit(parallel=True, cache=True)
def sum_pairs(g_pair, slots, prim_start, g_prim):  # pragma: no cover - compiled
    """``g_prim [N, F]`` = sum of the rows of ``g_pair [P, F]`` that belong to each primitive.

    Summed in float64, in ascending pair order, so the result does not depend
    on the thread count.
    """
    F = g_pair.shape[1]
    for n in prange(prim_start.shape[0] - 1):
        for f in range(F):
            s = 0.0
            for j in range(prim_start[n], prim_start[n + 1]):
                s += g_pair[slots[j], f]
            g_prim[n, f] = s
