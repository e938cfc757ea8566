"""The autoencoder's per-frame error as evidence for a degree of freedom the chart does not carry.

A hidden, lightly damped mode (the missing degree of freedom of paper §5) and an
unlogged periodic force leave the same residual force on the chart coordinate: a
sinusoid at a frequency of its own. Over one recorded segment that decays little,
the two differ by one damping ratio, which a few periods cannot resolve. The
image can: a mode is a motion of the scene that the ``d``-dimensional chart does
not encode, so the autoencoder, which decodes every frame from ``q`` alone, misses
it, and its per-frame reconstruction error ``ae_mse`` (:class:`~lagsplat.chart.Chart`)
rises and falls with that motion. A force moves only the encoded coordinate, and
the error it leaves is a function of the encoded state.

:func:`unencoded_oscillation` therefore regresses the error on a smooth function
of the encoded state (monomials of the standardised ``q`` and ``qdot``: total
degree 4 on a one-dimensional chart, 2 on a larger one) and a quadratic trend per
segment, then adds a cosine and a sine at the mode's frequency ``f``, its double
(the squared error of a displacement oscillates at ``2 f``) and its combination
tones with the motion's own frequency ``f_m`` (``f + f_m``, ``|f - f_m|``), each
kept where it is resolved from the motion's harmonics. The evidence is the
information criterion of the second fit over the first, on the ``Delta BIC``
scale, with half the frames counted as independent (neighbouring frames share
blur and the decoder's smoothness).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from itertools import combinations_with_replacement
from typing import Any

import numpy as np

__all__ = ["ImageError", "image_error_from_chart", "unencoded_oscillation"]


@dataclass
class ImageError:
    """The autoencoder's per-frame error beside the encoded position, per contiguous segment.

    Attributes:
        t: per segment, float64 ``[m]`` time, s.
        ae_mse: per segment, float64 ``[m]`` mean squared reconstruction error of each frame (image units squared).
        q: per segment, float64 ``[m,d]`` the chart's position (latent units).
    """

    t: list[np.ndarray]
    ae_mse: list[np.ndarray]
    q: list[np.ndarray]

    @property
    def n(self) -> int:
        """Number of frames over all segments."""
        return int(sum(len(t) for t in self.t))


def image_error_from_chart(chart: Any, which: int | None = 0) -> ImageError | None:
    """The chart's per-frame autoencoder error on its ``which`` segments (``0`` training, ``1`` held-out, ``None`` all).

    Returns:
        The :class:`ImageError`, or ``None`` where the chart records no usable error (absent, not finite,
        or constant: a chart built from a trajectory rather than from frames).
    """
    ae = getattr(chart, "ae_mse", None)
    if ae is None:
        return None
    ae = np.asarray(ae, np.float64).reshape(-1)
    if len(ae) != len(chart.t) or not np.all(np.isfinite(ae)) or float(np.ptp(ae)) <= 0.0:
        return None
    from lagsplat.diagnose.residual import chart_segments

    segs = [s for s in chart_segments(chart, which) if len(s) >= 8]
    if not segs:
        return None
    q = np.asarray(chart.q, np.float64)
    return ImageError([np.asarray(chart.t, np.float64)[s] for s in segs], [ae[s] for s in segs], [q[s] for s in segs])


def _state_columns(q: np.ndarray, qdot: np.ndarray, degree: int) -> np.ndarray:
    """Monomials of total degree 1 to ``degree`` in the standardised columns of ``q`` and ``qdot`` (``[m, k]``)."""
    z = np.concatenate([q, qdot], 1)
    z = (z - z.mean(0)) / np.maximum(z.std(0), 1e-300)
    cols = [np.prod(z[:, list(idx)], 1) for deg in range(1, degree + 1) for idx in combinations_with_replacement(range(z.shape[1]), deg)]
    return np.stack(cols, 1)


def unencoded_oscillation(img: ImageError, f_hz: float, f_motion_hz: float) -> dict[str, Any]:
    """Evidence that the autoencoder's error oscillates at a mode's frequency beyond what the encoded state explains.

    Args:
        img: the chart's per-frame error (:func:`image_error_from_chart`).
        f_hz: the mode's frequency, Hz.
        f_motion_hz: the encoded motion's dominant frequency, Hz.

    Returns:
        ``{"support", "frequencies_hz", "n_frames"}``: ``support`` on the ``Delta BIC`` scale (module
        docstring; 0 where no frequency is resolved or there are too few frames), and the frequencies tested.
    """
    T = max(float(t[-1] - t[0]) for t in img.t)
    sep = 0.5 / max(T, 1e-9)  # half a spectral bin of the longest segment
    harmonics = [k * f_motion_hz for k in range(1, 7)]
    fs: list[float] = []
    for f in (f_hz, 2.0 * f_hz, f_hz + f_motion_hz, abs(f_hz - f_motion_hz)):
        if f > 1.0 / T and all(abs(f - h) > sep for h in harmonics) and all(abs(f - g) > sep for g in fs):
            fs.append(float(f))
    d = img.q[0].shape[1]
    degree = 4 if d == 1 else 2
    X0, X1, y = [], [], []
    n_seg = len(img.t)
    for i, (t, e, q) in enumerate(zip(img.t, img.ae_mse, img.q)):
        dt = float(np.median(np.diff(t)))
        qdot = np.gradient(q, dt, axis=0)
        ts = (t - t.mean()) / max(float(t.std()), 1e-300)
        own = np.zeros((len(t), 3 * n_seg))
        own[:, 3 * i : 3 * i + 3] = np.stack([np.ones_like(ts), ts, ts * ts], 1)  # each segment's own level and trend
        base = np.column_stack([own, _state_columns(q, qdot, degree)])
        X0.append(base)
        X1.append(np.column_stack([base] + [g(2 * math.pi * f * t) for f in fs for g in (np.cos, np.sin)]))
        y.append(e)
    Y = np.concatenate(y)
    n_eff = len(Y) / 2.0
    k = 2 * len(fs)
    out: dict[str, Any] = {"support": 0.0, "frequencies_hz": fs, "n_frames": int(len(Y))}
    A0, A1 = np.concatenate(X0), np.concatenate(X1)
    if not fs or len(Y) <= A1.shape[1] + 4:
        return out
    ssr = [float(np.sum((Y - A @ np.linalg.lstsq(A, Y, rcond=None)[0]) ** 2)) for A in (A0, A1)]
    out["support"] = float(n_eff * math.log(max(ssr[0], 1e-300) / max(ssr[1], 1e-300)) - k * math.log(n_eff))
    return out
