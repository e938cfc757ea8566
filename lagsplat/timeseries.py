"""Signal helpers for latent trajectories: smoothing, derivative filters, the spectral peak, the chart-noise level.

The shared toolkit of the evaluation (:mod:`lagsplat.metrics`), the
simulators (:mod:`lagsplat.synth`), the integrators and the diagnosis, so
that the encoder trajectory and the simulated one always go through the same
code path (paper §4.1, "Metrics").

Conventions: trajectories are NumPy arrays with time on axis 0 (``q`` is
``[n, d]``), sampled every ``dt`` seconds; frequencies in Hz; ``G`` a
``d x d`` symmetric positive (semi-)definite metric (the visibility metric
``G_bar``), symmetrised before use. Every function validates its inputs and
raises :class:`ValueError` naming the offending argument.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy.ndimage import gaussian_filter1d

__all__ = [
    "half_cycle_amplitudes",
    "envelope_fit",
    "as_float_array",
    "check_finite",
    "check_dt",
    "as_metric",
    "as_trajectory",
    "spectral_peak_frequency",
    "forward_difference_velocity",
    "central_difference_velocity",
    "gaussian_smooth",
    "smoothing_edge",
    "chart_noise",
]


def as_float_array(x: Any, name: str) -> np.ndarray:
    """``x`` as a float64 array.

    Raises:
        ValueError: naming ``name`` if ``x`` cannot be converted.
    """
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: cannot convert to a float array ({exc})") from exc
    return a


def check_finite(a: np.ndarray, name: str) -> None:
    """Raise :class:`ValueError` naming ``name`` and the count if ``a`` holds NaN or inf."""
    if not np.all(np.isfinite(a)):
        bad = int(np.count_nonzero(~np.isfinite(a)))
        raise ValueError(f"{name}: contains {bad} non-finite value(s) (NaN or inf)")


def check_dt(dt: Any) -> float:
    """``dt`` as a positive finite float (seconds per sample).

    Raises:
        ValueError: if it is not a positive finite number.
    """
    try:
        dt_f = float(dt)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"dt must be a positive number of seconds, got {dt!r}") from exc
    if not math.isfinite(dt_f) or dt_f <= 0.0:
        raise ValueError(f"dt must be a positive finite number of seconds, got {dt!r}")
    return dt_f


def as_metric(G: Any, d: int | None, name: str = "G") -> np.ndarray:
    """Return the symmetrised float64 metric, checking it is ``[d, d]`` and finite."""
    Gm = as_float_array(G, name)
    if Gm.ndim != 2 or Gm.shape[0] != Gm.shape[1]:
        raise ValueError(f"{name} must be a square [d, d] matrix, got shape {Gm.shape}")
    if d is not None and Gm.shape[0] != d:
        raise ValueError(f"{name} has shape {Gm.shape} but the trajectory has d = {d} components")
    check_finite(Gm, name)
    return 0.5 * (Gm + Gm.T)


def as_trajectory(q: Any, name: str, min_len: int = 1) -> np.ndarray:
    """A ``[n, d]`` float64 trajectory with at least ``min_len`` samples."""
    a = as_float_array(q, name)
    if a.ndim != 2:
        raise ValueError(f"{name} must be a [n, d] array (time on axis 0), got shape {a.shape}")
    if a.shape[0] < min_len:
        raise ValueError(f"{name} needs at least {min_len} samples, got {a.shape[0]}")
    if a.shape[1] < 1:
        raise ValueError(f"{name} must have at least one component, got shape {a.shape}")
    check_finite(a, name)
    return a


def spectral_peak_frequency(
    x: Any,
    dt: float,
    G: Any | None = None,
    min_cycles: float = 1.5,
) -> float:
    """Dominant oscillation frequency of a sampled trajectory (windowed spectral peak).

    The estimator of the paper's free-oscillation frequency error, applied
    identically to the encoded trajectory and to a simulated rollout (paper
    Section 4.1 "Metrics"; the reference evaluation protocol):

    1. subtract the time mean;
    2. multiply by a Hann window of length ``n`` (``np.hanning(n)``);
    3. real FFT along time, bin ``k`` at ``f_k = k / (n dt)``;
    4. power per bin: ``|F_k|^2`` for a 1-D signal; for a ``[n, d]`` signal the
       G-aggregate ``Re(F_k)^T G Re(F_k) + Im(F_k)^T G Im(F_k)`` (``G = I`` when
       not given);
    5. zero the bins with ``f_k < min_cycles / (n dt)`` (slow drift, fewer than
       ``min_cycles`` cycles per window) and take the arg-max bin ``k*``;
    6. refine by a parabola through the log-power of bins ``k*-1, k*, k*+1``;
       the vertex offset ``delta`` is accepted only if the parabola is strictly
       concave and ``|delta| <= 0.5`` bin, otherwise the bin centre is returned.

    The refinement uses the power *before* the low-frequency cut for the two
    neighbours, so a peak just above the cut is still interpolated; a drift
    bin that dominates its neighbour cannot be accepted, because a concave
    parabola has ``|delta| <= 0.5`` only when the centre bin is the largest of
    the three.

    Args:
        x: ``[n]`` or ``[n, d]`` real samples, time on axis 0.
        dt: sampling interval in seconds (> 0).
        G: optional ``[d, d]`` symmetric positive semi-definite metric for the
            aggregate power of a ``[n, d]`` signal (symmetrised here). For a
            1-D signal only ``None`` or a ``[1, 1]`` matrix is allowed.
        min_cycles: bins with fewer than this many cycles per window are
            ignored (default 1.5, as the reference protocol).

    Returns:
        The peak frequency in Hz.

    Raises:
        ValueError: if ``n < 8``, ``x`` has more than two axes, contains NaN/inf,
            ``dt`` or ``min_cycles`` is invalid, ``G`` does not match, or the
            signal has no power above the cut (flat signal).
    """
    dt_f = check_dt(dt)
    a = as_float_array(x, "x")
    if a.ndim == 1:
        a = a[:, None]
        if G is not None:
            G1 = as_float_array(G, "G")
            if G1.size != 1:
                raise ValueError(f"x is 1-D, so G must be None or [1, 1], got shape {G1.shape}")
        Gm = None
    elif a.ndim == 2:
        Gm = None if G is None else as_metric(G, a.shape[1])
    else:
        raise ValueError(f"x must be [n] or [n, d], got shape {a.shape}")
    n = a.shape[0]
    if n < 8:
        raise ValueError(f"x needs at least 8 samples for a spectral estimate, got {n}")
    check_finite(a, "x")
    try:
        mc = float(min_cycles)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"min_cycles must be a number >= 0, got {min_cycles!r}") from exc
    if not math.isfinite(mc) or mc < 0:
        raise ValueError(f"min_cycles must be a finite number >= 0, got {min_cycles!r}")

    xc = (a - a.mean(axis=0, keepdims=True)) * np.hanning(n)[:, None]
    F = np.fft.rfft(xc, axis=0)  # [n//2 + 1, d]
    if Gm is None:
        power = np.sum(F.real**2 + F.imag**2, axis=1)
    else:
        power = np.einsum("ki,ij,kj->k", F.real, Gm, F.real) + np.einsum("ki,ij,kj->k", F.imag, Gm, F.imag)
    freqs = np.fft.rfftfreq(n, d=dt_f)
    df = 1.0 / (n * dt_f)

    cut = power.copy()
    cut[freqs < mc * df] = 0.0
    k = int(np.argmax(cut))
    peak = cut[k]
    # Power left by rounding after the mean subtraction of a constant signal is
    # ~ (1e-16 |x| sqrt(n))^2; a real oscillation of relative size 1e-10 has ~ (1e-10 |x| n)^2.
    g_scale = 1.0 if Gm is None else float(np.max(np.abs(np.linalg.eigvalsh(Gm))))
    floor = (1e-10 * float(np.max(np.abs(a))) * n) ** 2 * g_scale
    if not (peak > floor):
        raise ValueError(
            f"x is flat: no spectral power above the low-frequency cut ({mc} cycles per window, "
            f"{mc * df:.4g} Hz)"
        )

    offset = 0.0
    if 0 < k < len(power) - 1:
        p3 = power[k - 1 : k + 2]
        if np.all(p3 > 0.0):
            la, lb, lc = np.log(p3)
            denom = la - 2.0 * lb + lc
            if np.isfinite(denom) and denom < 0.0:
                delta = 0.5 * (la - lc) / denom
                if np.isfinite(delta) and abs(delta) <= 0.5:
                    offset = float(delta)
    return float((k + offset) * df)


def forward_difference_velocity(q: Any, dt: float) -> np.ndarray:
    """Second-order one-sided forward-difference velocity.

    ``v_s = (-3 q_s + 4 q_{s+1} - q_{s+2}) / (2 dt)`` for ``s = 0 .. n-3``: the
    initial velocity of every evaluation rollout (reference evaluation
    protocol). Exact for quadratics in time.

    Args:
        q: ``[n, ...]`` trajectory, time on axis 0 (typically ``[n, d]``), ``n >= 3``.
        dt: sampling interval (> 0); the velocity is in units of ``q`` per second
            (pass ``dt = 1`` for per-frame units).

    Returns:
        float64 ``[n - 2, ...]``; row ``s`` is the velocity at sample ``s``.

    Raises:
        ValueError: if ``n < 3``, ``q`` is 0-D, non-finite, or ``dt <= 0``.
    """
    dt_f = check_dt(dt)
    a = as_float_array(q, "q")
    if a.ndim < 1 or a.shape[0] < 3:
        raise ValueError(f"q needs at least 3 samples on axis 0 for a forward difference, got shape {a.shape}")
    check_finite(a, "q")
    return (-3.0 * a[:-2] + 4.0 * a[1:-1] - a[2:]) / (2.0 * dt_f)


def central_difference_velocity(q: Any, dt: float, k: int = 1) -> tuple[np.ndarray, int]:
    """Central-difference velocity with stride ``k``.

    ``v_s = (q_{s+k} - q_{s-k}) / (2 k dt)`` for every ``s`` with both
    neighbours inside the trajectory, i.e. ``s = k .. n-1-k`` (the velocity
    target of the LNN training windows).

    Args:
        q: ``[n, ...]`` trajectory, time on axis 0, ``n >= 2k + 1``.
        dt: sampling interval (> 0); velocity in units of ``q`` per second.
        k: stride in samples (>= 1).

    Returns:
        ``(v, offset)``: ``v`` is float64 ``[n - 2k, ...]`` and ``offset = k``;
        ``v[i]`` is the velocity at sample ``i + offset``.

    Raises:
        ValueError: if ``k < 1``, ``n < 2k + 1``, non-finite input, or ``dt <= 0``.
    """
    dt_f = check_dt(dt)
    k_i = int(k)
    if k_i != k or k_i < 1:
        raise ValueError(f"k must be an integer >= 1, got {k!r}")
    a = as_float_array(q, "q")
    if a.ndim < 1 or a.shape[0] < 2 * k_i + 1:
        raise ValueError(
            f"q needs at least 2k+1 = {2 * k_i + 1} samples on axis 0 for a central difference, got shape {a.shape}"
        )
    check_finite(a, "q")
    v = (a[2 * k_i :] - a[: -2 * k_i]) / (2.0 * k_i * dt_f)
    return v, k_i


def gaussian_smooth(q: Any, sigma_frames: float) -> np.ndarray:
    """Gaussian smoothing along time (axis 0), edges by replication.

    ``scipy.ndimage.gaussian_filter1d(q, sigma_frames, axis=0, mode="nearest")``;
    the reference smooths encoded latents and pressures with ``sigma = 1``
    frame before setting up rollouts. The filter
    is non-causal.

    Args:
        q: ``[n, ...]`` array, time on axis 0, ``n >= 1``.
        sigma_frames: standard deviation in samples (>= 0); 0 returns a copy.

    Returns:
        float64 array of the same shape.

    Raises:
        ValueError: if ``sigma_frames < 0`` or not finite, ``q`` is 0-D/empty,
            or ``q`` contains NaN/inf.
    """
    a = as_float_array(q, "q")
    if a.ndim < 1 or a.shape[0] < 1:
        raise ValueError(f"q must have at least one sample on axis 0, got shape {a.shape}")
    check_finite(a, "q")
    try:
        s = float(sigma_frames)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"sigma_frames must be a number >= 0, got {sigma_frames!r}") from exc
    if not math.isfinite(s) or s < 0.0:
        raise ValueError(f"sigma_frames must be a finite number >= 0, got {sigma_frames!r}")
    if s == 0.0:
        return a.copy()
    return gaussian_filter1d(a, s, axis=0, mode="nearest")


def smoothing_edge(sigma_frames: float) -> int:
    """Frames at each end of a :func:`gaussian_smooth`'ed segment that its edge replication reaches.

    ``ceil(4 sigma)`` (scipy's kernel is truncated at 4 sigma). Within them the
    smoothed trajectory is pulled towards a constant, so a velocity read there
    is biased low: at a mid-swing first frame, about half the true speed with
    ``sigma = 1``. Rollouts that must start from the true state start past them.
    """
    return int(math.ceil(4.0 * max(float(sigma_frames), 0.0)))


def half_cycle_amplitudes(p: np.ndarray, t: np.ndarray, period_frames: float) -> tuple[np.ndarray, np.ndarray]:
    """Turning-point amplitudes of an oscillation ``p [n]`` sampled at times ``t [n]`` (s).

    The half-cycle amplitude is half the difference of consecutive alternating extrema (insensitive to
    the rest offset), placed at their mid time; extrema closer than ``0.35 period_frames`` are merged
    (scipy ``find_peaks`` distance).

    Returns:
        ``(t_k [m], A_k [m])``; both empty with fewer than two extrema.
    """
    from scipy.signal import find_peaks

    gap = max(1, int(0.35 * period_frames))
    i_max, _ = find_peaks(p, distance=gap)
    i_min, _ = find_peaks(-p, distance=gap)
    idx = np.sort(np.concatenate([i_max, i_min]))
    if len(idx) < 2:
        return np.zeros(0), np.zeros(0)
    return 0.5 * (t[idx[1:]] + t[idx[:-1]]), 0.5 * np.abs(np.diff(p[idx]))


def envelope_fit(t: np.ndarray, a: np.ndarray, form: str) -> tuple[np.ndarray, float]:
    """Fit an envelope to amplitudes ``a [m]`` at times ``t [m]``: ``(coef [2], sse)``.

    ``form="linear"``: ``A = c0 + c1 t`` (dry friction); ``"exponential"``: ``log A = c0 + c1 t``, least squares
    weighted by ``A`` (viscous damping; ``-c1`` is the decay rate ``1/tau``). ``sse`` is over the amplitudes themselves.
    """
    X = np.stack([np.ones_like(t), t], 1)
    if form == "linear":
        c = np.linalg.lstsq(X, a, rcond=None)[0]
        return c, float(np.sum((a - X @ c) ** 2))
    w = np.abs(a)
    c = np.linalg.lstsq(X * w[:, None], np.log(a) * w, rcond=None)[0]
    return c, float(np.sum((a - np.exp(X @ c)) ** 2))


def chart_noise(segments: Sequence[np.ndarray]) -> np.ndarray:
    """Per-sample white-noise level of a trajectory, from its fourth difference.

    ``Delta^4 q`` cancels a smooth signal (to ``(w dt)^4``) and multiplies white
    noise of std ``s`` by ``sqrt(70)``; the scale is the robust MAD estimate
    ``1.4826 median|x - median x|`` pooled over the segments.

    Args:
        segments: list of ``[m,d]`` raw trajectories (each ``m >= 5``; shorter ones are skipped).

    Returns:
        float64 ``[d]`` noise standard deviation per coordinate.

    Raises:
        ValueError: if no segment has 5 samples.
    """
    d4 = [np.diff(np.asarray(s, np.float64), 4, axis=0) for s in segments if len(s) >= 5]
    if not d4:
        raise ValueError("chart_noise needs a segment of at least 5 samples")
    x = np.concatenate(d4, 0)
    mad = 1.4826 * np.median(np.abs(x - np.median(x, 0)), 0)
    return mad / math.sqrt(70.0)
