"""Evaluation metrics: the one place each reported quantity is computed.

Every number the report cites (frequency error, latent NRMSE, image error,
where rollouts start) is computed here, with the signal helpers of
:mod:`lagsplat.timeseries` (smoothing, velocities, spectral peak), so that the
encoder trajectory and the simulated trajectory always go through the *same*
code path (paper, Section "Experiments / Protocol", paragraph "Metrics";
reference evaluation protocol).

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

from lagsplat.timeseries import (
    as_float_array,
    as_metric,
    as_trajectory,
    check_finite,
    smoothing_edge,
)

__all__ = [
    "top_direction",
    "normalise_trace",
    "project",
    "g_rms_spread",
    "latent_nrmse",
    "relative_error",
    "window_starts",
    "image_mse",
    "rollout_start",
]










# --------------------------------------------------------------------------- metric helpers
def top_direction(G: Any) -> np.ndarray:
    """Unit eigenvector of the largest eigenvalue of the symmetrised ``G``.

    The "most visible" latent direction onto which the cited frequency error
    is projected (reference evaluation protocol). The sign
    is fixed so that the component of largest magnitude is positive (the
    first such component on ties), making the result deterministic.

    Args:
        G: ``[d, d]`` real matrix (symmetrised here).

    Returns:
        float64 ``[d]`` with unit Euclidean norm.

    Raises:
        ValueError: if ``G`` is not square or contains NaN/inf.
    """
    Gm = as_metric(G, None)
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
    scaled to trace ``d`` with no ridge ("Aggregation
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
    Gm = as_metric(G, None)
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
    qa = as_trajectory(q, "q")
    u = as_float_array(direction, "direction")
    if u.ndim != 1 or u.shape[0] != qa.shape[1]:
        raise ValueError(f"direction must be [d] with d = {qa.shape[1]}, got shape {u.shape}")
    check_finite(u, "direction")
    return qa @ u


def g_rms_spread(q: Any, G: Any) -> float:
    """G-RMS amplitude of a trajectory about its mean.

    ``q_std = sqrt( mean_t (q_t - q_bar)^T G (q_t - q_bar) )`` (reference
    evaluation protocol); the denominator of
    :func:`latent_nrmse`.

    Args:
        q: ``[n, d]`` trajectory (``n >= 1``).
        G: ``[d, d]`` metric (symmetrised here).

    Returns:
        The spread, in latent units (>= 0).

    Raises:
        ValueError: on mismatched shapes or non-finite input.
    """
    qa = as_trajectory(q, "q")
    Gm = as_metric(G, qa.shape[1])
    dq = qa - qa.mean(axis=0, keepdims=True)
    val = float(np.mean(np.einsum("ti,ij,tj->t", dq, Gm, dq)))
    return math.sqrt(max(val, 0.0))


def latent_nrmse(q_pred: Any, q_true: Any, G: Any, q_std: float) -> float:
    """Latent NRMSE of rollouts against the encoded trajectory.

    ``NRMSE = sqrt( mean_{windows, steps} Delta^T G Delta ) / q_std`` with
    ``Delta = q_pred - q_true``. This equals the reference's
    ``sqrt(mse_lat * d) / q_std`` with ``mse_lat = mean Delta^T G Delta / d``
    (paper Section 4.1 "Metrics"; the reference evaluation protocol). With ``q_std`` from
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
    p = as_float_array(q_pred, "q_pred")
    t = as_float_array(q_true, "q_true")
    if p.ndim not in (2, 3):
        raise ValueError(f"q_pred must be [N, H, d] (or [H, d]), got shape {p.shape}")
    if p.shape != t.shape:
        raise ValueError(f"q_pred has shape {p.shape} but q_true has shape {t.shape}")
    if p.size == 0:
        raise ValueError(f"q_pred is empty (shape {p.shape})")
    check_finite(p, "q_pred")
    check_finite(t, "q_true")
    Gm = as_metric(G, p.shape[-1])
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
    (reference evaluation protocol).

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
    ``[lo, hi)``, *with replacement* (the reference evaluation protocol).

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
    reference's per-step MSE over C x H x W.

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
        a = as_float_array(raw, name)
        check_finite(a, name)
        if a.size and (a.min() < -1e-6 or a.max() > 1.0 + 1e-6):
            raise ValueError(f"{name} has values outside [0, 1] (min {a.min():.4g}, max {a.max():.4g})")
        arrs.append(a)
    p, t = arrs
    if p.shape != t.shape:
        raise ValueError(f"pred has shape {p.shape} but target has shape {t.shape}")
    if p.size == 0:
        raise ValueError("image_mse: empty images")
    return float(np.mean((p - t) ** 2))


def rollout_start(sigma_frames: float, n: int, room: int) -> int:
    """First rollout start in a :func:`gaussian_smooth`'ed segment of ``n`` frames.

    :func:`smoothing_edge` frames in, or earlier when the segment is too short to
    leave ``room`` frames after it (never below 0).
    """
    return min(smoothing_edge(sigma_frames), max(int(n) - int(room), 0))
