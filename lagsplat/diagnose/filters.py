"""Signal processing shared by the residual and the localisation: the chart-noise level, Gaussian-derivative kernel norms, odd padding.

The residual of :mod:`lagsplat.diagnose.residual` differentiates the encoded
trajectory with Gaussian derivative filters (standard deviation ``sigma``
frames, kernels truncated at 6 sigma); the noise of the chart propagates into
it through the norm of those kernels (:func:`kernel_norm`), and its level is
read from the trajectory's fourth difference (:func:`~lagsplat.timeseries.chart_noise`,
re-exported here).
"""

from __future__ import annotations


import numpy as np
from scipy.ndimage import gaussian_filter1d

from lagsplat.timeseries import chart_noise

__all__ = ["chart_noise", "kernel_norm", "pad_odd"]


def kernel_norm(sigma: float, order: int) -> float:
    """``|g|_2`` of the discrete Gaussian derivative kernel of this order (per frame^order).

    White noise of standard deviation ``s`` per sample comes out of the filter
    with standard deviation ``s |g|_2`` (divide by ``dt^order`` for physical units).

    Args:
        sigma: kernel standard deviation, frames (> 0).
        order: derivative order (0, 1, 2, ...).
    """
    n = int(8 * sigma) + 1
    imp = np.zeros(2 * n + 1)
    imp[n] = 1.0
    return float(np.linalg.norm(gaussian_filter1d(imp, sigma, order=order, mode="constant", truncate=6.0)))


def pad_odd(x: np.ndarray, P: int) -> tuple[np.ndarray, int]:
    """Pad ``[m, ...]`` by ``P`` samples at both ends by odd reflection about the end samples.

    The padding keeps value and slope continuous at the ends, so a derivative
    filter sees no step there.

    Args:
        x: ``[m, ...]`` samples (``m >= 2``).
        P: samples wanted at each end (at most ``m - 1`` are added).

    Returns:
        ``(padded [m + 2 P', ...], P')`` with ``P' = min(P, m - 1)``.
    """
    m = len(x)
    P = min(P, m - 1)
    left = 2 * x[0] - x[P:0:-1]
    right = 2 * x[-1] - x[-2 : -P - 2 : -1]
    return np.concatenate([left, x, right], 0), P
