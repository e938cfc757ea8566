"""Evaluation metrics: the one place each reported quantity is computed.

Every number the report cites (frequency error, latent NRMSE, image error, the
velocities and smoothing used to set up rollouts) is computed here, so that the
encoder trajectory and the simulated trajectory always go through the *same*
code path (paper, Section "Experiments / Protocol", paragraph "Metrics";
reference evaluation protocol, notes section 9).

Conventions
-----------
* Trajectories are NumPy arrays with time on axis 0: ``q`` is ``[n, d]``
  (``n`` samples of a ``d``-dimensional latent state), sampled every ``dt``
  seconds.
* ``G`` is a ``d x d`` symmetric positive (semi-)definite metric (the
  visibility metric of the paper). Latent norms are G-norms,
  ``|v|_G^2 = v^T G v``; functions symmetrise ``G`` before use.
* Frequencies are in Hz, times in seconds, ``dt`` in seconds per sample.
* Every function validates its inputs and raises :class:`ValueError` with a
  message naming the offending argument.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy.ndimage import gaussian_filter1d

__all__ = [
    "spectral_peak_frequency",
    "top_direction",
    "normalise_trace",
    "project",
    "g_rms_spread",
    "latent_nrmse",
    "relative_error",
    "window_starts",
    "image_mse",
    "forward_difference_velocity",
    "central_difference_velocity",
    "gaussian_smooth",
    "smoothing_edge",
    "rollout_start",
]


# --------------------------------------------------------------------------- helpers
def _as_float_array(x: Any, name: str) -> np.ndarray:
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: cannot convert to a float array ({exc})") from exc
    return a


def _check_finite(a: np.ndarray, name: str) -> None:
    if not np.all(np.isfinite(a)):
        bad = int(np.count_nonzero(~np.isfinite(a)))
        raise ValueError(f"{name}: contains {bad} non-finite value(s) (NaN or inf)")


def _check_dt(dt: Any) -> float:
    try:
        dt_f = float(dt)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"dt must be a positive number of seconds, got {dt!r}") from exc
    if not math.isfinite(dt_f) or dt_f <= 0.0:
        raise ValueError(f"dt must be a positive finite number of seconds, got {dt!r}")
    return dt_f


def _metric(G: Any, d: int | None, name: str = "G") -> np.ndarray:
    """Return the symmetrised float64 metric, checking it is ``[d, d]`` and finite."""
    Gm = _as_float_array(G, name)
    if Gm.ndim != 2 or Gm.shape[0] != Gm.shape[1]:
        raise ValueError(f"{name} must be a square [d, d] matrix, got shape {Gm.shape}")
    if d is not None and Gm.shape[0] != d:
        raise ValueError(f"{name} has shape {Gm.shape} but the trajectory has d = {d} components")
    _check_finite(Gm, name)
    return 0.5 * (Gm + Gm.T)


def _trajectory(q: Any, name: str, min_len: int = 1) -> np.ndarray:
    """A ``[n, d]`` float64 trajectory with at least ``min_len`` samples."""
    a = _as_float_array(q, name)
    if a.ndim != 2:
        raise ValueError(f"{name} must be a [n, d] array (time on axis 0), got shape {a.shape}")
    if a.shape[0] < min_len:
        raise ValueError(f"{name} needs at least {min_len} samples, got {a.shape[0]}")
    if a.shape[1] < 1:
        raise ValueError(f"{name} must have at least one component, got shape {a.shape}")
    _check_finite(a, name)
    return a


# --------------------------------------------------------------------------- frequency
def spectral_peak_frequency(
    x: Any,
    dt: float,
    G: Any | None = None,
    min_cycles: float = 1.5,
) -> float:
    """Dominant oscillation frequency of a sampled trajectory (windowed spectral peak).

    The estimator of the paper's free-oscillation frequency error, applied
    identically to the encoded trajectory and to a simulated rollout (paper
    Section 4.1 "Metrics"; reference evaluation protocol, notes section 9.2
    "Frequency estimator"):

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
    dt_f = _check_dt(dt)
    a = _as_float_array(x, "x")
    if a.ndim == 1:
        a = a[:, None]
        if G is not None:
            G1 = _as_float_array(G, "G")
            if G1.size != 1:
                raise ValueError(f"x is 1-D, so G must be None or [1, 1], got shape {G1.shape}")
        Gm = None
    elif a.ndim == 2:
        Gm = None if G is None else _metric(G, a.shape[1])
    else:
        raise ValueError(f"x must be [n] or [n, d], got shape {a.shape}")
    n = a.shape[0]
    if n < 8:
        raise ValueError(f"x needs at least 8 samples for a spectral estimate, got {n}")
    _check_finite(a, "x")
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


# --------------------------------------------------------------------------- metric helpers
def top_direction(G: Any) -> np.ndarray:
    """Unit eigenvector of the largest eigenvalue of the symmetrised ``G``.

    The "most visible" latent direction onto which the cited frequency error
    is projected (reference evaluation protocol, notes section 9.2). The sign
    is fixed so that the component of largest magnitude is positive (the
    first such component on ties), making the result deterministic.

    Args:
        G: ``[d, d]`` real matrix (symmetrised here).

    Returns:
        float64 ``[d]`` with unit Euclidean norm.

    Raises:
        ValueError: if ``G`` is not square or contains NaN/inf.
    """
    Gm = _metric(G, None)
    if Gm.shape[0] < 1:
        raise ValueError("G must be at least 1 x 1")
    _, vecs = np.linalg.eigh(Gm)
    v = vecs[:, -1].copy()
    i = int(np.argmax(np.abs(v)))
    if v[i] < 0:
        v = -v
    return v / np.linalg.norm(v)


def normalise_trace(G: Any, d: int | None = None) -> np.ndarray:
    """Symmetrise ``G`` and scale it to trace ``d``: ``G_sym * d / trace(G)``.

    The aggregation metric of the reference protocol is the visibility metric
    scaled to trace ``d`` with no ridge (notes section 9.2, "Aggregation
    metric"), so a G-norm of an isotropic error equals its Euclidean norm on
    average.

    Args:
        G: ``[d, d]`` real matrix.
        d: target trace; defaults to the size of ``G``.

    Returns:
        float64 ``[d, d]`` symmetric matrix with trace ``d``.

    Raises:
        ValueError: if ``G`` is not square/finite, its trace is not positive,
            or ``d`` is not positive.
    """
    Gm = _metric(G, None)
    target = Gm.shape[0] if d is None else d
    try:
        target_f = float(target)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"d must be a positive number, got {d!r}") from exc
    if not math.isfinite(target_f) or target_f <= 0:
        raise ValueError(f"d must be a positive number, got {d!r}")
    tr = float(np.trace(Gm))
    if not math.isfinite(tr) or tr <= 0.0:
        raise ValueError(f"G must have a positive trace to be normalised, got trace {tr}")
    return Gm * (target_f / tr)


def project(q: Any, direction: Any) -> np.ndarray:
    """Project a trajectory onto a direction: ``q @ direction``.

    The direction is used as given (:func:`top_direction` returns a unit
    vector); no mean is removed.

    Args:
        q: ``[n, d]`` trajectory.
        direction: ``[d]`` vector.

    Returns:
        float64 ``[n]``.

    Raises:
        ValueError: on mismatched shapes or non-finite input.
    """
    qa = _trajectory(q, "q")
    u = _as_float_array(direction, "direction")
    if u.ndim != 1 or u.shape[0] != qa.shape[1]:
        raise ValueError(f"direction must be [d] with d = {qa.shape[1]}, got shape {u.shape}")
    _check_finite(u, "direction")
    return qa @ u


def g_rms_spread(q: Any, G: Any) -> float:
    """G-RMS amplitude of a trajectory about its mean.

    ``q_std = sqrt( mean_t (q_t - q_bar)^T G (q_t - q_bar) )`` (reference
    evaluation protocol, notes section 9.2 "Scales"); the denominator of
    :func:`latent_nrmse`.

    Args:
        q: ``[n, d]`` trajectory (``n >= 1``).
        G: ``[d, d]`` metric (symmetrised here).

    Returns:
        The spread, in latent units (>= 0).

    Raises:
        ValueError: on mismatched shapes or non-finite input.
    """
    qa = _trajectory(q, "q")
    Gm = _metric(G, qa.shape[1])
    dq = qa - qa.mean(axis=0, keepdims=True)
    val = float(np.mean(np.einsum("ti,ij,tj->t", dq, Gm, dq)))
    return math.sqrt(max(val, 0.0))


def latent_nrmse(q_pred: Any, q_true: Any, G: Any, q_std: float) -> float:
    """Latent NRMSE of rollouts against the encoded trajectory.

    ``NRMSE = sqrt( mean_{windows, steps} Delta^T G Delta ) / q_std`` with
    ``Delta = q_pred - q_true``. This equals the reference's
    ``sqrt(mse_lat * d) / q_std`` with ``mse_lat = mean Delta^T G Delta / d``
    (paper Section 4.1 "Metrics"; reference evaluation protocol, notes
    section 9.2 "Cycle error and NRMSE"). With ``q_std`` from
    :func:`g_rms_spread`, 1.0 means no better than predicting the mean and 0
    is a perfect prediction. The value is invariant under a change of chart
    ``q -> P q`` when ``G -> P^-T G P^-1``.

    Windows with non-finite states must be dropped by the caller; this
    function refuses them.

    Args:
        q_pred: ``[N, H, d]`` predicted states (``[H, d]`` is read as one window).
        q_true: same shape, the encoded states they are compared with.
        G: ``[d, d]`` metric (symmetrised here).
        q_std: the normalising G-RMS spread (> 0).

    Returns:
        The NRMSE (dimensionless, >= 0).

    Raises:
        ValueError: on mismatched shapes, non-finite values, or ``q_std <= 0``.
    """
    p = _as_float_array(q_pred, "q_pred")
    t = _as_float_array(q_true, "q_true")
    if p.ndim not in (2, 3):
        raise ValueError(f"q_pred must be [N, H, d] (or [H, d]), got shape {p.shape}")
    if p.shape != t.shape:
        raise ValueError(f"q_pred has shape {p.shape} but q_true has shape {t.shape}")
    if p.size == 0:
        raise ValueError(f"q_pred is empty (shape {p.shape})")
    _check_finite(p, "q_pred")
    _check_finite(t, "q_true")
    Gm = _metric(G, p.shape[-1])
    try:
        s = float(q_std)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"q_std must be a positive number, got {q_std!r}") from exc
    if not math.isfinite(s) or s <= 0.0:
        raise ValueError(f"q_std must be a positive finite number, got {q_std!r}")
    delta = (p - t).reshape(-1, p.shape[-1])
    mse = float(np.mean(np.einsum("ti,ij,tj->t", delta, Gm, delta)))
    return math.sqrt(max(mse, 0.0)) / s


def relative_error(value: float, reference: float) -> float:
    """Relative error ``|value - reference| / |reference|``.

    The frequency error of the paper is ``relative_error(f_sim, f_enc)``
    (reference evaluation protocol, notes section 9.2 "Cited number").

    Raises:
        ValueError: if either argument is not finite or ``reference == 0``.
    """
    try:
        v = float(value)
        r = float(reference)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"value and reference must be numbers, got {value!r}, {reference!r}") from exc
    if not (math.isfinite(v) and math.isfinite(r)):
        raise ValueError(f"value and reference must be finite, got {v}, {r}")
    if r == 0.0:
        raise ValueError("reference must be non-zero for a relative error")
    return abs(v - r) / abs(r)


def window_starts(lo: int, hi: int, n_windows: int = 50, seed: int = 0) -> np.ndarray:
    """Random rollout start indices, as the published protocol draws them.

    ``np.random.default_rng(seed).integers(lo, hi, n_windows)``: uniform in
    ``[lo, hi)``, *with replacement* (reference evaluation protocol, notes
    sections 9.1 and 9.2).

    Args:
        lo: smallest allowed start (inclusive).
        hi: largest start plus one (exclusive).
        n_windows: number of starts (>= 1).
        seed: generator seed.

    Returns:
        int64 ``[n_windows]``.

    Raises:
        ValueError: if ``hi <= lo`` or ``n_windows < 1``.
    """
    lo_i, hi_i, n_i = int(lo), int(hi), int(n_windows)
    if hi_i <= lo_i:
        raise ValueError(f"window_starts: empty range, need hi > lo, got lo={lo_i}, hi={hi_i}")
    if n_i < 1:
        raise ValueError(f"window_starts: n_windows must be >= 1, got {n_i}")
    return np.random.default_rng(int(seed)).integers(lo_i, hi_i, n_i).astype(np.int64)


def image_mse(pred: Any, target: Any) -> float:
    """Mean squared error between two images (or image stacks) in ``[0, 1]``.

    The mean runs over every element (frames, channels, rows, columns), as the
    reference's per-step MSE over C x H x W (notes section 9.1).

    Args:
        pred: float array in ``[0, 1]``, any shape.
        target: float array of the same shape, in ``[0, 1]``.

    Returns:
        The MSE (in squared intensity units, range ``[0, 1]``).

    Raises:
        ValueError: on shape mismatch, empty input, integer arrays (convert
            uint8 frames with ``/ 255`` first), NaN/inf, or values outside
            ``[0, 1]``.
    """
    arrs = []
    for name, arr in (("pred", pred), ("target", target)):
        raw = np.asarray(arr)
        if raw.dtype.kind in "biu":
            raise ValueError(f"{name} has integer dtype {raw.dtype}; pass floats in [0, 1] (e.g. frames / 255)")
        a = _as_float_array(raw, name)
        _check_finite(a, name)
        if a.size and (a.min() < -1e-6 or a.max() > 1.0 + 1e-6):
            raise ValueError(f"{name} has values outside [0, 1] (min {a.min():.4g}, max {a.max():.4g})")
        arrs.append(a)
    p, t = arrs
    if p.shape != t.shape:
        raise ValueError(f"pred has shape {p.shape} but target has shape {t.shape}")
    if p.size == 0:
        raise ValueError("image_mse: empty images")
    return float(np.mean((p - t) ** 2))


# --------------------------------------------------------------------------- velocities / smoothing
def forward_difference_velocity(q: Any, dt: float) -> np.ndarray:
    """Second-order one-sided forward-difference velocity.

    ``v_s = (-3 q_s + 4 q_{s+1} - q_{s+2}) / (2 dt)`` for ``s = 0 .. n-3``: the
    initial velocity of every evaluation rollout (reference evaluation
    protocol, notes sections 9.1 and 9.2). Exact for quadratics in time.

    Args:
        q: ``[n, ...]`` trajectory, time on axis 0 (typically ``[n, d]``), ``n >= 3``.
        dt: sampling interval (> 0); the velocity is in units of ``q`` per second
            (pass ``dt = 1`` for per-frame units).

    Returns:
        float64 ``[n - 2, ...]``; row ``s`` is the velocity at sample ``s``.

    Raises:
        ValueError: if ``n < 3``, ``q`` is 0-D, non-finite, or ``dt <= 0``.
    """
    dt_f = _check_dt(dt)
    a = _as_float_array(q, "q")
    if a.ndim < 1 or a.shape[0] < 3:
        raise ValueError(f"q needs at least 3 samples on axis 0 for a forward difference, got shape {a.shape}")
    _check_finite(a, "q")
    return (-3.0 * a[:-2] + 4.0 * a[1:-1] - a[2:]) / (2.0 * dt_f)


def central_difference_velocity(q: Any, dt: float, k: int = 1) -> tuple[np.ndarray, int]:
    """Central-difference velocity with stride ``k``.

    ``v_s = (q_{s+k} - q_{s-k}) / (2 k dt)`` for every ``s`` with both
    neighbours inside the trajectory, i.e. ``s = k .. n-1-k`` (the velocity
    target of the LNN training windows, notes section 8.6).

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
    dt_f = _check_dt(dt)
    k_i = int(k)
    if k_i != k or k_i < 1:
        raise ValueError(f"k must be an integer >= 1, got {k!r}")
    a = _as_float_array(q, "q")
    if a.ndim < 1 or a.shape[0] < 2 * k_i + 1:
        raise ValueError(
            f"q needs at least 2k+1 = {2 * k_i + 1} samples on axis 0 for a central difference, got shape {a.shape}"
        )
    _check_finite(a, "q")
    v = (a[2 * k_i :] - a[: -2 * k_i]) / (2.0 * k_i * dt_f)
    return v, k_i


def gaussian_smooth(q: Any, sigma_frames: float) -> np.ndarray:
    """Gaussian smoothing along time (axis 0), edges by replication.

    ``scipy.ndimage.gaussian_filter1d(q, sigma_frames, axis=0, mode="nearest")``;
    the reference smooths encoded latents and pressures with ``sigma = 1``
    frame before setting up rollouts (notes sections 9.1 and 9.2). The filter
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
    a = _as_float_array(q, "q")
    if a.ndim < 1 or a.shape[0] < 1:
        raise ValueError(f"q must have at least one sample on axis 0, got shape {a.shape}")
    _check_finite(a, "q")
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


def rollout_start(sigma_frames: float, n: int, room: int) -> int:
    """First rollout start in a :func:`gaussian_smooth`'ed segment of ``n`` frames.

    :func:`smoothing_edge` frames in, or earlier when the segment is too short to
    leave ``room`` frames after it (never below 0).
    """
    return min(smoothing_edge(sigma_frames), max(int(n) - int(room), 0))
