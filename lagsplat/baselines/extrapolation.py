"""The extrapolation protocol of paper §4.3 (Table 3): train on the first part of a clip, predict the rest, then far past it.

Every model is read in one chart, the frozen LaGSplat encoder's, as a *predictor*: a function that
rolls a state ``(q0, qdot0)`` forward ``n`` frames. The numbers, for each model:

* **Rendering** (when frames and the autoencoder are given): PSNR of the decoded prediction against
  the real frames of the longest held-out segment, the mean and the first and last predicted frame,
  beside the LaGSplat autoencoder floor on the same frames (the decoded encoding of each frame).
* **Frequency error**: the spectral peak of the prediction over the held-out segment against that of
  the encoded real video there (:func:`lagsplat.timeseries.spectral_peak_frequency`).
* **Dissipation-coefficient error**: the envelope decay rate ``1/tau`` of a free rollout over the
  filmed window (the held-out segment's episode, from its first frame), against the rate of the
  encoded real video over the same window; ``|rate_model - rate_real| / rate_real``.
* **Amplitude left after 1000 s**: a free rollout from the held-out start, the half peak-to-peak
  over its last natural period over that of its first, along the most visible direction of ``G_bar``.

A dissipative model must reach 0 % on the last row whatever its weights (paper §3.2, App. A.2);
an unconstrained predictor may keep a sustained orbit.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from lagsplat import metrics, timeseries
from lagsplat.chart import Chart
from lagsplat.dynamics.integrators import initial_state
from lagsplat.io.clip import HELD_OUT

__all__ = ["Predictor", "ExtrapolationConfig", "decay_rate", "amplitude_left", "extrapolation_metrics"]


@dataclass
class ExtrapolationConfig:
    """Settings of the extrapolation protocol (``conf/config.yaml``, group ``extrapolation``).

    Attributes:
        long_s: length of the long free extrapolation, s (paper Table 3: 1000).
        sigma: smoothing of the encoded trajectory before the initial states are read, frames.
        render_batch: decoding batch of the rendering rows.
    """

    long_s: float = 1000.0
    sigma: float = 1.0
    render_batch: int = 64

#: ``predictor(q0 [d], qdot0 [d], dt, n) -> [n, d]`` positions of a free rollout, frames ``dt`` s apart (the first is ``q0``).
Predictor = Callable[[np.ndarray, np.ndarray, float, int], np.ndarray]


def decay_rate(p: np.ndarray, dt: float, f_hz: float) -> float:
    """Envelope decay rate ``1/tau`` (1/s) of an oscillation ``p [n]``: ``log`` of its half-cycle amplitudes fitted
    linearly in time, weighted by the amplitude squared (an exponential envelope). NaN with fewer than three half cycles.

    The half-cycle amplitude is half the difference of consecutive extrema (insensitive to the rest offset).
    """
    from scipy.signal import find_peaks

    gap = max(1, int(0.35 / (f_hz * dt))) if math.isfinite(f_hz) and f_hz > 0 else 5
    idx = np.sort(np.concatenate([find_peaks(p, distance=gap)[0], find_peaks(-p, distance=gap)[0]]))
    if len(idx) < 4:
        return float("nan")
    a = 0.5 * np.abs(np.diff(p[idx]))
    t = 0.5 * (idx[1:] + idx[:-1]) * dt
    keep = a > 1e-9 * max(float(a.max()), 1e-300)
    if keep.sum() < 3:
        return float("nan")
    w = a[keep]
    X = np.stack([np.ones(int(keep.sum())), t[keep]], 1)
    c = np.linalg.lstsq(X * w[:, None], np.log(a[keep]) * w, rcond=None)[0]
    return float(-c[1])


def amplitude_left(p: np.ndarray, dt: float, f_hz: float) -> float:
    """Half peak-to-peak of ``p [n]`` over its last natural period over that over its first (1: a sustained orbit, 0: at rest)."""
    m = max(2, int(round(1.0 / (f_hz * dt))))
    first, last = float(np.ptp(p[:m])), float(np.ptp(p[-m:]))
    return last / first if first > 0 else float("nan")


def _filmed_window(chart: Chart, ho: np.ndarray) -> np.ndarray:
    """Frames of the held-out segment's episode (training and held-out), in order: the filmed window."""
    ep = np.asarray(chart.episode)
    return np.flatnonzero(ep == ep[ho[0]])


def extrapolation_metrics(
    chart: Chart, predictor: Predictor, long_s: float = 1000.0, sigma: float = 1.0, ae: Any | None = None, frames: np.ndarray | None = None,
    batch: int = 64,
) -> dict[str, Any]:
    """The protocol of the module docstring for one model.

    Args:
        chart: the frozen chart every trajectory is read in (its held-out frames are the ones predicted).
        predictor: the model's free rollout (:data:`Predictor`).
        long_s: length of the long free extrapolation, s (paper: 1000).
        sigma: smoothing of the encoded trajectory before the initial state is read, frames.
        ae, frames: the Stage-1 autoencoder and the clip's uint8 ``[T,H,W,3]`` frames for the rendering
            rows (``None``: no rendering rows).
        batch: decoding batch.

    Returns:
        ``{"freq_error", "f_model_hz", "f_real_hz", "dissipation_error", "rate_model_per_s", "rate_real_per_s",
        "amplitude_left", "long_s", "psnr_mean", "psnr_first", "psnr_last", "psnr_ae_floor_mean", "n_held_out"}``
        (rendering entries ``None`` without frames).

    Raises:
        ValueError: if the chart has no held-out segment of at least 16 frames.
    """
    segs = [s for s in chart.segments(HELD_OUT) if len(s) >= 16]
    if not segs:
        raise ValueError("the chart has no held-out segment of 16 frames or more to predict")
    ho = max(segs, key=len)
    dt = float(np.median(np.diff(chart.t)))
    top = metrics.top_direction(chart.G_bar)
    q_s = timeseries.gaussian_smooth(chart.q, sigma)
    q0, v0 = (x.numpy()[0] for x in initial_state(q_s, np.array([ho[0]]), dt))
    pred = np.asarray(predictor(q0, v0, dt, len(ho)), np.float64)
    f_real = timeseries.spectral_peak_frequency(metrics.project(q_s[ho], top), dt)
    f_model = timeseries.spectral_peak_frequency(metrics.project(pred, top), dt) if np.isfinite(pred).all() else float("nan")

    win = _filmed_window(chart, ho)
    w0, w1 = (x.numpy()[0] for x in initial_state(q_s, np.array([win[0]]), dt))
    p_win = metrics.project(np.asarray(predictor(w0, w1, dt, len(win)), np.float64), top)
    rate_real = decay_rate(metrics.project(q_s[win], top), dt, f_real)
    rate_model = decay_rate(p_win, dt, f_real) if np.isfinite(p_win).all() else float("nan")

    p_long = metrics.project(np.asarray(predictor(q0, v0, dt, int(round(long_s / dt)) + 1), np.float64), top)
    left = amplitude_left(p_long, dt, f_real) if np.isfinite(p_long).all() else float("nan")
    out: dict[str, Any] = {
        "f_real_hz": f_real, "f_model_hz": f_model, "freq_error": metrics.relative_error(f_model, f_real) if math.isfinite(f_model) else float("nan"),
        "rate_real_per_s": rate_real, "rate_model_per_s": rate_model,
        "dissipation_error": abs(rate_model - rate_real) / abs(rate_real) if rate_real else float("nan"),
        "amplitude_left": left, "long_s": float(long_s), "n_held_out": int(len(ho)),
        "psnr_mean": None, "psnr_first": None, "psnr_last": None, "psnr_ae_floor_mean": None,
    }  # fmt: skip
    if ae is not None and frames is not None:
        from lagsplat.evaluate.common import decoded_psnr_ssim

        psnr, _ = decoded_psnr_ssim(ae, chart, pred, frames[ho], batch)
        floor, _ = decoded_psnr_ssim(ae, chart, chart.q[ho], frames[ho], batch)
        fin = lambda x: x[np.isfinite(x)]  # noqa: E731 (an exact decode is inf dB)
        out.update(psnr_mean=float(np.mean(fin(psnr))), psnr_first=float(psnr[0]), psnr_last=float(psnr[-1]), psnr_ae_floor_mean=float(np.mean(fin(floor))))
    return out
