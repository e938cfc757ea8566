"""The soft-robot protocol's settings and windows: index conventions, the window starts, flat-pressure intervals and the spectral peak (paper §4.4, Table 4; the rollouts and scores are :mod:`lagsplat.evaluate.krauss_rollouts`, the driver :func:`lagsplat.evaluate.krauss.evaluate_krauss`)."""

from __future__ import annotations

import math

import numpy as np

from lagsplat import metrics, timeseries
from lagsplat.evaluate.settings import KraussEvalConfig  # noqa: F401  (re-exported: the protocol's settings)

DT_KRAUSS = 1001 / 60000
"""Frame interval of the published recordings, seconds (59.94 fps; the reference code)."""




# --------------------------------------------------------------------------- index conventions
def n_states(horizon_s: float, dt: float) -> int:
    """Number of states of a ``horizon_s`` horizon, initial state included: ``round(horizon_s / dt)``.

    0.5 s at 59.94 fps gives ``round(29.97) = 30`` (the reference code).

    Raises:
        ValueError: if the result is below 3 (no forward-difference velocity).
    """
    n = int(round(float(horizon_s) / float(dt)))
    if n < 3:
        raise ValueError(f"horizon {horizon_s} s at dt = {dt} s gives {n} states; need at least 3")
    return n


def mse_window_starts(n: int, horizon: int, skip: int, n_windows: int = 50, seed: int = 0) -> np.ndarray:
    """Start frames of the multi-step MSE: ``default_rng(seed).integers(skip, n - horizon, n_windows)``.

    Uniform with replacement (duplicates possible, as published; the reference code).

    Args:
        n: frames in the validation clip.
        horizon: states per rollout (30).
        skip: static head (480).

    Returns:
        int64 ``[n_windows]``, every ``s`` with ``skip <= s < n - horizon``.

    Raises:
        ValueError: if ``n - horizon <= skip`` (validation clip too short).
    """
    if n - horizon <= skip:
        raise ValueError(f"validation clip has {n} frames: need more than skip + horizon = {skip + horizon}")
    return metrics.window_starts(skip, n - horizon, n_windows, seed)


def ae_floor_frames(n: int, skip: int, count: int = 1000) -> np.ndarray:
    """Frames of the AE floor: ``linspace(skip, n - 1, count)`` truncated to integers (the reference code).

    Raises:
        ValueError: if ``n - 1 < skip``.
    """
    if n - 1 < skip:
        raise ValueError(f"validation clip has {n} frames, fewer than the {skip}-frame head")
    return np.linspace(skip, n - 1, int(count)).astype(np.int64)


def leading_duplicates(frames: np.ndarray, first: int = 6, ratio: float = 50.0) -> int:
    """Number of leading duplicated frames to trim before the §9.2 criteria.

    ``m_j = MSE(frame_{j+1}, frame_j)`` for the first ``first`` pairs; frames
    are trimmed from the start while ``m_j < median(m) / ratio`` (the published
    "Setup": "consecutive-frame MSE < median/50 among the first 6"; the exact
    loop of the reference is not documented, this is our reading).

    Args:
        frames: uint8 or float ``[n, H, W, C]`` (or any ``[n, ...]``).

    Returns:
        ``k >= 0``: frames ``[k, n)`` are kept.
    """
    f = np.asarray(frames[: first + 1], np.float64)
    if len(f) < 3:
        return 0
    m = ((f[1:] - f[:-1]) ** 2).reshape(len(f) - 1, -1).mean(1)
    thr = float(np.median(m)) / ratio
    k = 0
    while k < len(m) and m[k] < thr:
        k += 1
    return k


def flat_intervals(P_raw: np.ndarray, lo: int, min_len: int, step_tol: float = 0.01, total_tol: float = 0.05, max_intervals: int = 20) -> list[tuple[int, int]]:
    """Constant-pressure (free-oscillation) intervals of a pressure record (the reference code).

    On frames ``[lo, n)``: ``amp`` = max over chambers of the peak-to-peak of
    ``P_raw[lo:]``; frame ``t`` is flat when ``max_c |P[t+1, c] - P[t, c]| <
    step_tol * amp`` (the last frame is flat when the one before it is, so
    a depressurised tail runs to the end of the clip; the reference's exact
    edge convention is not documented, this is our reading); runs of at least ``min_len`` flat frames are kept unless their own
    peak-to-peak (max over chambers) exceeds ``total_tol * amp``; at most
    ``max_intervals``, longest first (earliest first among equal lengths).

    Args:
        P_raw: ``[n, n_c]`` raw (unsmoothed) pressures, any unit.
        lo: first frame considered (480).
        min_len: shortest run, frames (120).

    Returns:
        ``[(a, b), ...]`` half-open frame ranges ``[a, b)`` into ``P_raw``
        (possibly empty). If ``P_raw[lo:]`` is constant (``amp = 0``, e.g. a
        clip whose validation part after the head is all tail) the whole of
        ``[lo, n)`` is one interval, where the reference's tolerance
        ``0.01 * amp = 0`` would find none.

    Raises:
        ValueError: if ``P_raw`` is not ``[n, n_c]`` with ``n_c >= 1`` or ``lo`` is outside it.
    """
    P = np.asarray(P_raw, np.float64)
    if P.ndim != 2 or P.shape[1] < 1:
        raise ValueError(f"P_raw must be [n, n_chambers], got shape {P.shape}")
    n = len(P)
    if not 0 <= lo < n:
        raise ValueError(f"lo = {lo} outside the {n}-frame pressure record")
    seg = P[lo:]
    amp = float((seg.max(0) - seg.min(0)).max())
    if amp <= 0:  # constant over all of [lo, n): one run (the reference's 0-tolerance finds none)
        return [(lo, n)] if n - lo >= min_len else []
    step = np.abs(np.diff(seg, axis=0)).max(1)  # frame t -> t + 1
    flat = np.append(step < step_tol * amp, step[-1:] < step_tol * amp if len(step) else [False])
    runs, a = [], None
    for i, f in enumerate(np.append(flat, False)):
        if f and a is None:
            a = i
        elif not f and a is not None:
            if i - a >= min_len:
                r = seg[a:i]
                if float((r.max(0) - r.min(0)).max()) <= total_tol * amp:
                    runs.append((lo + a, lo + i))
            a = None
    runs.sort(key=lambda ab: (-(ab[1] - ab[0]), ab[0]))
    return runs[: int(max_intervals)]


def peak_frequency(x: np.ndarray, dt: float, G: np.ndarray | None = None, min_cycles: float = 1.5) -> float:
    """Spectral peak frequency as the published estimator computes it, Hz (the reference code).

    Mean removed, Hann window, real FFT; power ``|F|^2`` (1-D) or
    ``Re F^T G Re F + Im F^T G Im F``; bins below ``min_cycles`` cycles per
    window zeroed; arg-max bin refined by a parabola through the log-power of
    the three bins, kept if strictly concave with offset ``<= 0.5`` bin.
    This is :func:`lagsplat.timeseries.spectral_peak_frequency` except at the
    cut: the reference zeroes the low bins *before* the refinement, so a peak
    in the first bin above the cut (bin 2 for ``min_cycles = 1.5``), whose
    lower neighbour is zeroed, is returned unrefined at the bin centre.

    Args:
        x: ``[n]`` or ``[n, d]`` samples (time on axis 0), ``n >= 8``.
        dt: sampling interval, s.
        G: ``[d, d]`` metric of the aggregate power, or ``None``.
        min_cycles: low-frequency cut, cycles per window.

    Returns:
        Frequency in Hz.

    Raises:
        ValueError: as :func:`lagsplat.timeseries.spectral_peak_frequency`
            (flat signal, too few samples, bad shapes).
    """
    f = timeseries.spectral_peak_frequency(x, dt, G, min_cycles)
    df = 1.0 / (len(x) * float(dt))
    k1 = math.ceil(float(min_cycles))  # lowest bin kept: its lower neighbour is always zeroed
    if k1 >= 1 and f < (k1 + 0.5) * df:
        return k1 * df
    return f


# --------------------------------------------------------------------------- rollouts
