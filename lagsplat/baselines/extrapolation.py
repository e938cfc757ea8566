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
from typing import Any, Optional

import numpy as np

from lagsplat import metrics, timeseries
from lagsplat.chart import Chart
from lagsplat.dynamics.integrators import initial_state
from lagsplat.io.clip import HELD_OUT, TRAIN

__all__ = [
    "Predictor", "ExtrapolationConfig", "ProtocolWindows", "protocol_windows", "decay_rate", "amplitude_left", "extrapolation_metrics",
    "frame_extrapolation_metrics", "encode_in_chart", "in_training_range", "frames_psnr", "finite_mean", "ae_floor_psnr",
    "real_trace", "model_trace",
]  # fmt: skip


@dataclass
class ExtrapolationConfig:
    """Settings of the extrapolation protocol (``conf/config.yaml``, group ``extrapolation``).

    Attributes:
        long_s: length of the long free extrapolation, s (paper Table 3: 1000).
        figure_s: free extrapolation kept for the figure (paper Fig. 5) from the held-out start, s.
        sigma: smoothing of the encoded trajectory before the initial states are read, frames.
        render_batch: decoding batch of the rendering rows.
        gp2d: also fit and score GP-2D (:mod:`lagsplat.baselines.gp2d`; settings: the ``gp2d`` group).
        gaussian_prediction_frames: a folder of frames predicted by the original GaussianPrediction
            (:mod:`lagsplat.baselines.gp_frames`), scored like GP-2D; ``None``: no such row.
    """

    long_s: float = 1000.0
    figure_s: float = 30.0
    sigma: float = 1.0
    render_batch: int = 64
    gp2d: bool = True
    gaussian_prediction_frames: Optional[str] = None

#: ``predictor(q0 [d], qdot0 [d], dt, n) -> [n, d]`` positions of a free rollout, frames ``dt`` s apart (the first is ``q0``).
Predictor = Callable[[np.ndarray, np.ndarray, float, int], np.ndarray]


def decay_rate(p: np.ndarray, dt: float, f_hz: float) -> float:
    """Envelope decay rate ``1/tau`` (1/s) of an oscillation ``p [n]``: the exponential
    :func:`~lagsplat.timeseries.envelope_fit` of its :func:`~lagsplat.timeseries.half_cycle_amplitudes`
    (insensitive to the rest offset). NaN with fewer than three non-vanishing half cycles.
    """
    period = 1.0 / (f_hz * dt) if math.isfinite(f_hz) and f_hz > 0 else 5 / 0.35
    t, a = timeseries.half_cycle_amplitudes(p, np.arange(len(p)) * dt, period)
    keep = a > 1e-9 * max(float(a.max()), 1e-300) if len(a) else np.zeros(0, bool)
    if keep.sum() < 3:
        return float("nan")
    c, _ = timeseries.envelope_fit(t[keep], a[keep], "exponential")
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


@dataclass
class ProtocolWindows:
    """The frames every model of the protocol predicts, read once from the chart.

    Attributes:
        ho: the longest held-out segment (frame indices; predicted from its first frame).
        win: the filmed window, the held-out segment's episode (the dissipation row's free rollout).
        dt: frame period, s.
        top: ``[d]`` most visible direction of ``G_bar`` (every row reads the trajectory along it).
        q_s: ``[T,d]`` smoothed encoded trajectory.
        f_real: spectral peak of the encoded real video over ``ho``, Hz.
        n_long: states of the long free rollout (``long_s / dt + 1``).
        m_period: frames in one natural period at ``f_real`` (the amplitude-left row's window).
        n_near: states of the free extrapolation the figure shows from the held-out start (``figure_s / dt + 1``,
            at least the held-out segment, at most ``n_long``).
    """

    ho: np.ndarray
    win: np.ndarray
    dt: float
    top: np.ndarray
    q_s: np.ndarray
    f_real: float
    n_long: int
    m_period: int
    n_near: int = 0


def protocol_windows(chart: Chart, long_s: float = 1000.0, sigma: float = 1.0, figure_s: float = 30.0) -> ProtocolWindows:
    """:class:`ProtocolWindows` of a chart.

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
    f_real = timeseries.spectral_peak_frequency(metrics.project(q_s[ho], top), dt)
    m = max(2, int(round(1.0 / (f_real * dt)))) if math.isfinite(f_real) and f_real > 0 else 2
    n_long = int(round(long_s / dt)) + 1
    n_near = min(n_long, max(len(ho), int(round(figure_s / dt)) + 1))
    return ProtocolWindows(ho, _filmed_window(chart, ho), dt, top, q_s, f_real, n_long, m, n_near)


def real_trace(w: ProtocolWindows, chart: Chart) -> dict[str, Any]:
    """The encoded real video over the filmed window for the figure: ``{"t" [n] s from the window's first frame,
    "p" [n] (smoothed ``q`` along ``w.top``), "t_held_out" (s, where the prediction starts), "t_end" (s)}``."""
    t = chart.t[w.win] - chart.t[w.win[0]]
    return {"t": t.tolist(), "p": metrics.project(w.q_s[w.win], w.top).tolist(),
            "t_held_out": float(chart.t[w.ho[0]] - chart.t[w.win[0]]), "t_end": float(t[-1])}  # fmt: skip


def model_trace(p_near: np.ndarray | None, p_far: np.ndarray | None, w: ProtocolWindows, long_s: float) -> dict[str, Any]:
    """A model's free extrapolation for the figure (paper Fig. 5), along ``w.top``: ``{"near" [n] from the held-out
    start, "far" [m] its last natural period ending ``long_s`` s after it, "dt"}`` (``None`` entries: not predicted)."""
    as_list = lambda x: None if x is None else np.asarray(x, np.float64).tolist()  # noqa: E731
    return {"near": as_list(p_near), "far": as_list(p_far), "dt": w.dt, "long_s": float(long_s)}


def _dynamics_rows(w: ProtocolWindows, chart: Chart, pred_ho: np.ndarray, p_win: np.ndarray, p_long: np.ndarray, long_s: float) -> dict[str, Any]:
    """Frequency, dissipation and amplitude-left rows from a model's held-out prediction ``[n_ho,d]``, its free rollout
    over the filmed window (projected, ``[len(win)]``) and its long rollout (projected; the amplitude row reads its first
    and last natural period only)."""
    f_model = timeseries.spectral_peak_frequency(metrics.project(pred_ho, w.top), w.dt) if np.isfinite(pred_ho).all() else float("nan")
    rate_real = decay_rate(metrics.project(w.q_s[w.win], w.top), w.dt, w.f_real)
    rate_model = decay_rate(p_win, w.dt, w.f_real) if np.isfinite(p_win).all() else float("nan")
    left = amplitude_left(p_long, w.dt, w.f_real) if np.isfinite(p_long).all() else float("nan")
    return {
        "f_real_hz": w.f_real, "f_model_hz": f_model,
        "freq_error": metrics.relative_error(f_model, w.f_real) if math.isfinite(f_model) else float("nan"),
        "rate_real_per_s": rate_real, "rate_model_per_s": rate_model,
        "dissipation_error": abs(rate_model - rate_real) / abs(rate_real) if rate_real else float("nan"),
        "amplitude_left": left, "long_s": float(long_s), "n_held_out": int(len(w.ho)),
        "psnr_mean": None, "psnr_first": None, "psnr_last": None, "psnr_ae_floor_mean": None,
    }  # fmt: skip


def finite_mean(x: np.ndarray, empty: float = math.inf) -> float:
    """Mean of the finite entries of ``x`` (an exact frame is ``inf`` dB), ``empty`` when there are none."""
    fin = x[np.isfinite(x)]
    return float(np.mean(fin)) if len(fin) else float(empty)


def frames_psnr(pred: np.ndarray, real: np.ndarray) -> np.ndarray:
    """Per-frame PSNR (dB, scikit-image, data range 1) of uint8 frames ``pred`` against ``real``, both ``[n,H,W,3]``."""
    from skimage.metrics import peak_signal_noise_ratio

    with np.errstate(divide="ignore"):
        return np.array([peak_signal_noise_ratio(r / 255.0, p / 255.0, data_range=1.0) for p, r in zip(pred, real)])


def ae_floor_psnr(ae: Any, chart: Chart, frames: np.ndarray, idx: np.ndarray, batch: int, empty: float = math.inf) -> float:
    """Mean PSNR (dB) of the LaGSplat autoencoder on the clip's frames ``idx``: the floor the rendering rows are read against."""
    from lagsplat.evaluate.common import decoded_image_errors

    _, floor, _ = decoded_image_errors(ae, chart, chart.q[idx], frames[idx], batch)
    return finite_mean(floor, empty)


def extrapolation_metrics(
    chart: Chart, predictor: Predictor, long_s: float = 1000.0, sigma: float = 1.0, ae: Any | None = None, frames: np.ndarray | None = None,
    batch: int = 64, figure_s: float = 30.0,
) -> dict[str, Any]:
    """The protocol of the module docstring for one model that predicts in the chart.

    Args:
        chart: the frozen chart every trajectory is read in (its held-out frames are the ones predicted).
        predictor: the model's free rollout (:data:`Predictor`).
        long_s: length of the long free extrapolation, s (paper: 1000).
        sigma: smoothing of the encoded trajectory before the initial state is read, frames.
        ae, frames: the Stage-1 autoencoder and the clip's uint8 ``[T,H,W,3]`` frames for the rendering
            rows (``None``: no rendering rows).
        batch: decoding batch.
        figure_s: free extrapolation kept in ``trace`` for the figure, s.

    Returns:
        ``{"freq_error", "f_model_hz", "f_real_hz", "dissipation_error", "rate_model_per_s", "rate_real_per_s",
        "amplitude_left", "long_s", "psnr_mean", "psnr_first", "psnr_last", "psnr_ae_floor_mean", "n_held_out", "trace"}``
        (rendering entries ``None`` without frames; ``trace``: :func:`model_trace`).

    Raises:
        ValueError: if the chart has no held-out segment of at least 16 frames.
    """
    w = protocol_windows(chart, long_s, sigma, figure_s)
    state = lambda i: (x.numpy()[0] for x in initial_state(w.q_s, np.array([i]), w.dt))  # noqa: E731
    q0, v0 = state(w.ho[0])
    pred = np.asarray(predictor(q0, v0, w.dt, len(w.ho)), np.float64)
    w0, w1 = state(w.win[0])
    p_win = metrics.project(np.asarray(predictor(w0, w1, w.dt, len(w.win)), np.float64), w.top)
    p_long = metrics.project(np.asarray(predictor(q0, v0, w.dt, w.n_long), np.float64), w.top)
    out = _dynamics_rows(w, chart, pred, p_win, p_long, long_s)
    out["trace"] = model_trace(p_long[: w.n_near], p_long[-w.m_period :], w, long_s)
    if ae is not None and frames is not None:
        from lagsplat.evaluate.common import decoded_image_errors

        _, psnr, _ = decoded_image_errors(ae, chart, pred, frames[w.ho], batch)
        out.update(psnr_mean=finite_mean(psnr, math.nan), psnr_first=float(psnr[0]), psnr_last=float(psnr[-1]),
                   psnr_ae_floor_mean=ae_floor_psnr(ae, chart, frames, w.ho, batch))  # fmt: skip
    return out


def encode_in_chart(ae: Any, chart: Chart, frames: np.ndarray, batch: int = 64) -> np.ndarray:
    """uint8 frames ``[n,H,W,3]`` read through the frozen encoder into the chart: whitened ``q [n,d]`` (float64)."""
    import torch

    with torch.no_grad():
        return chart.to_whitened(ae.encode_frames(frames, batch)).double().numpy()


def in_training_range(q: np.ndarray, chart: Chart, margin: float = 0.1) -> float:
    """Fraction of states ``q [n,d]`` inside the training encodings' range on every axis, widened by ``margin`` of the
    range on each side: near 1 means the encoder reads the predicted frames without extrapolating."""
    tr = chart.q[np.asarray(chart.split) == TRAIN]
    lo, hi = tr.min(0), tr.max(0)
    pad = margin * (hi - lo)
    inside = ((q >= lo - pad) & (q <= hi + pad)).all(1)
    return float(inside.mean()) if len(q) else float("nan")


def frame_extrapolation_metrics(
    chart: Chart, ae: Any, frames: np.ndarray, w: ProtocolWindows, pred_ho: np.ndarray, pred_win: np.ndarray | None,
    pred_long: np.ndarray | None, long_s: float, batch: int = 64, pred_near: np.ndarray | None = None,
) -> dict[str, Any]:
    """The protocol for a model that predicts frames (GP-2D, imported GaussianPrediction frames), every frame read
    through the frozen LaGSplat encoder so its trajectory lives in the same chart.

    Args:
        chart, ae: the frozen chart and Stage-1 autoencoder.
        frames: the clip's uint8 frames ``[T,H,W,3]``.
        w: :func:`protocol_windows` of the chart.
        pred_ho: uint8 ``[len(w.ho),H,W,3]``, the prediction of the held-out frames.
        pred_win: uint8 ``[len(w.win),H,W,3]``, a free prediction over the filmed window, or ``None`` (no dissipation row).
        pred_long: uint8 ``[2 m,H,W,3]``, the first and the last natural period (``m = w.m_period`` frames each) of
            a free prediction ``long_s`` long, or ``None`` (no amplitude row).
        long_s: the long prediction's length, s.
        pred_near: uint8 ``[n,H,W,3]``, the free prediction from the held-out start the figure shows (its first
            ``w.n_near`` frames or fewer), or ``None`` (the figure shows the held-out prediction).

    Returns:
        The keys of :func:`extrapolation_metrics`, the PSNR rows of the predicted frames themselves against the real
        ones, plus ``encoded_in_range`` (:func:`in_training_range` of the encoded held-out prediction).

    Raises:
        ValueError: on frame arrays of the wrong length or size.
    """
    for name, x, n in (("held-out", pred_ho, len(w.ho)), ("window", pred_win, len(w.win)), ("long", pred_long, 2 * w.m_period)):
        if x is not None and (len(x) != n or x.shape[1:] != frames.shape[1:]):
            raise ValueError(f"{name} prediction: {tuple(x.shape)} frames, expected {n} of {tuple(frames.shape[1:])}")
    q_ho = encode_in_chart(ae, chart, pred_ho, batch)
    nan = np.full(2, np.nan)
    p_win = metrics.project(encode_in_chart(ae, chart, pred_win, batch), w.top) if pred_win is not None else np.full(len(w.win), np.nan)
    p_long = metrics.project(encode_in_chart(ae, chart, pred_long, batch), w.top) if pred_long is not None else nan
    out = _dynamics_rows(w, chart, q_ho, p_win, p_long, long_s)
    p_near = metrics.project(encode_in_chart(ae, chart, pred_near[: w.n_near], batch) if pred_near is not None else q_ho, w.top)
    out["trace"] = model_trace(p_near, p_long[-w.m_period :] if pred_long is not None else None, w, long_s)
    if pred_win is None:
        out.update(rate_model_per_s=None, dissipation_error=None)
    if pred_long is None:
        out.update(amplitude_left=None)
    psnr = frames_psnr(pred_ho, frames[w.ho])
    out.update(psnr_mean=finite_mean(psnr), psnr_first=float(psnr[0]), psnr_last=float(psnr[-1]),
               psnr_ae_floor_mean=ae_floor_psnr(ae, chart, frames, w.ho, batch), encoded_in_range=in_training_range(q_ho, chart))  # fmt: skip
    return out
