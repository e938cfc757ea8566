"""Forward-mode derivative (a Jacobian-vector product) of the compiled CPU rasteriser, for the visibility metric.

The visibility metric ``G_bar = mean_q J^T J`` (paper Eq. 6) needs ``J = d image / d q`` column by column.
Through the pure-torch rasteriser each column is a forward-mode pass over per-tile tensors (and forward-mode
AD there pulls in torch's compiler stack); :func:`jvp_kernel` carries the tangent through the same
front-to-back compositing as :func:`lagsplat.render.cpu_kernels.forward_kernel`, pixel by pixel:

* ``alpha_n = o_n exp(-d2_n / 2)`` with ``d2_n`` the conic's quadratic form at the pixel, so
  ``d alpha_n = exp(-d2_n / 2) (d o_n - o_n d(d2_n) / 2)``, and ``d(d2_n)`` from the mean's tangent
  (``-2 (a dx + b dy) d mu_x - 2 (b dx + c dy) d mu_y``); zero where the rule's cuts set ``alpha`` to 0 or
  clip it at ``ALPHA_MAX``;
* ``T_{n+1} = T_n (1 - alpha_n)``: ``d T_{n+1} = d T_n (1 - alpha_n) - T_n d alpha_n``;
* ``C = sum_n c_n alpha_n T_n + T_final bg``: ``d C = sum_n c_n (d alpha_n T_n + alpha_n d T_n) + d T_final bg``.

Only the means and opacities carry tangents: the conditioned decoder's covariances and colours do not
depend on the state (:meth:`lagsplat.models.decoder.ConditionedGaussians.render_jvp`).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from lagsplat.render.cpu_kernels import ALPHA_MAX, ALPHA_MIN, TILE, exp_neg, tile_origin

_NPIX = TILE * TILE
_F0, _F1 = np.float32(0.0), np.float32(1.0)

__all__ = ["jvp_kernel"]


@njit(parallel=True, cache=True, error_model="numpy")
def jvp_kernel(pairs, key_start, means, conic, opac, r2, colors, bg, d_means, d_opac, x0, x1, y0, y1, H, W, ntx, n_tiles, out, out_t):  # pragma: no cover
    """Front-to-back compositing with the tangent (module docstring); fills ``out`` and ``out_t`` ``[B,C,H,W]``.

    Args as :func:`lagsplat.render.cpu_kernels.forward_kernel`, plus ``d_means [N,2]`` and ``d_opac [N]``, the
    tangents of the primitives' means (px) and opacities.
    """
    n_keys = key_start.shape[0] - 1
    C = colors.shape[1]
    for key in prange(n_keys):
        b, ox, oy, xlim = tile_origin(key, n_tiles, ntx, W)
        T = np.ones(_NPIX, np.float32)
        dT = np.zeros(_NPIX, np.float32)
        acc = np.zeros((C, _NPIX), np.float32)
        dacc = np.zeros((C, _NPIX), np.float32)
        for p in range(key_start[key], key_start[key + 1]):
            n = pairs[p]
            row0 = max(y0[n], oy) - oy
            i0, i1 = row0 * TILE, (min(y1[n], oy + TILE - 1, H - 1) - oy + 1) * TILE
            fx0 = np.float32(ox + 0.5) - means[n, 0]
            fy0 = np.float32(oy + row0 + 0.5) - means[n, 1]
            ca, cb, cc = conic[n, 0], conic[n, 1], conic[n, 2]
            o, rr = opac[n], r2[n]
            dmx, dmy, do = d_means[n, 0], d_means[n, 1], d_opac[n]
            for i in range(i1 - i0):
                j = i0 + i
                ix = i & (TILE - 1)
                dx = fx0 + np.float32(ix)
                dy = fy0 + np.float32(i >> 4)
                d2 = ca * dx * dx + np.float32(2.0) * cb * dx * dy + cc * dy * dy
                e = exp_neg(np.float32(-0.5) * d2)
                a_raw = o * e
                a = min(a_raw, ALPHA_MAX)
                if not (d2 <= rr and a >= ALPHA_MIN and ix < xlim):
                    continue
                if a_raw < ALPHA_MAX:
                    dd2 = np.float32(-2.0) * ((ca * dx + cb * dy) * dmx + (cb * dx + cc * dy) * dmy)
                    da = e * (do - np.float32(0.5) * o * dd2)
                else:
                    da = _F0
                t, dt = T[j], dT[j]
                w, dw = a * t, da * t + a * dt
                for c in range(C):
                    acc[c, j] += colors[n, c] * w
                    dacc[c, j] += colors[n, c] * dw
                T[j] = t * (_F1 - a)
                dT[j] = dt * (_F1 - a) - t * da
        for iy in range(min(TILE, H - oy)):
            for ix in range(xlim):
                i = iy * TILE + ix
                for c in range(C):
                    out[b, c, oy + iy, ox + ix] = acc[c, i] + T[i] * bg[c]
                    out_t[b, c, oy + iy, ox + ix] = dacc[c, i] + dT[i] * bg[c]
