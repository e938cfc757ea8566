"""GP-2D on the extrapolation protocol: fit on the filmed training frames, forecast the rest and far past it, render.

GP-2D is a re-implementation of GaussianPrediction's motion-prediction structure (Zhao et al.,
SIGGRAPH 2024) in the image plane, not the original code: the field of
:mod:`lagsplat.baselines.gp2d_field` and the forecaster of :mod:`lagsplat.baselines.gp2d_forecast`.
Protocol (paper §4.3, GaussianPrediction's "pure" prediction setting): the field is fitted on the
training frames of the held-out segment's episode that precede it (normalised time over them),
the forecaster on their fitted key-point states; the held-out frames are forecast from the last
``history`` fitted states, the dissipation row's free prediction over the filmed window from the
first ``history`` ones, and the long prediction from the held-out start. Only the frames the
protocol reads are rendered.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from lagsplat.baselines.gp2d_field import GP2DConfig, GP2DField, fit_field
from lagsplat.baselines.gp2d_forecast import KeypointForecaster, forecast, train_forecaster
from lagsplat.chart import Chart
from lagsplat.io.clip import TRAIN

__all__ = ["GP2D", "fit_gp2d", "gp2d_predictions"]


@dataclass
class GP2D:
    """A fitted GP-2D: the field, its key-point states on the fitted frames ``[T_fit,K,4]`` and the forecaster."""

    field: GP2DField
    states: np.ndarray
    forecaster: KeypointForecaster
    history: dict[str, Any]

    @torch.no_grad()
    def render(self, states: np.ndarray, batch: int = 32) -> np.ndarray:
        """Key-point states ``[n,K,4]`` -> uint8 frames ``[n,H,W,3]``."""
        out = []
        for i in range(0, len(states), batch):
            S = torch.as_tensor(np.asarray(states[i : i + batch]), dtype=torch.float32)
            img = self.field.render(*self.field.blend(S)).clamp(0, 1)
            out.append((img.permute(0, 2, 3, 1).numpy() * 255.0 + 0.5).astype(np.uint8))
        return np.concatenate(out) if out else np.zeros((0, self.field.height, self.field.width, 3), np.uint8)


def fit_gp2d(frames: np.ndarray, cfg: GP2DConfig, seed: int = 0, log_every: int = 0) -> GP2D:
    """Fit the field on uint8 frames ``[T,H,W,3]`` (evenly spaced), then the forecaster on their key-point states.

    Raises:
        ValueError: with fewer frames than the forecaster's history plus one.
    """
    if len(frames) < cfg.gcn_history + 1:
        raise ValueError(f"GP-2D needs at least {cfg.gcn_history + 1} training frames, got {len(frames)}")
    field, h_field = fit_field(frames, cfg, seed, log_every)
    with torch.no_grad():
        states = field.keypoint_states(torch.linspace(0.0, 1.0, len(frames))).numpy()
    fc, h_gcn = train_forecaster(states, cfg, seed)
    return GP2D(field, states, fc, {"field": h_field, "forecaster": h_gcn})


def gp2d_predictions(chart: Chart, frames: np.ndarray, w: Any, cfg: GP2DConfig, seed: int = 0, log_every: int = 0) -> tuple[dict[str, np.ndarray], GP2D, list[int]]:
    """Fit GP-2D on the training frames before the held-out segment and render what the protocol reads.

    Args:
        chart: the frozen chart (its split and episodes pick the frames).
        frames: the clip's uint8 frames ``[T,H,W,3]``.
        w: :class:`~lagsplat.baselines.extrapolation.ProtocolWindows` of the chart.
        cfg, seed: GP-2D's settings and seed.

    Returns:
        ``({"held_out", "near", "window", "long"}, model, fitted frame indices)``: uint8 frames (``window`` ``None``
        when the filmed window does not start on the fitted frames; ``near``: the free prediction from the held-out
        start over the figure's stretch) as :func:`~lagsplat.baselines.extrapolation.frame_extrapolation_metrics` takes them.

    Raises:
        ValueError: if the held-out segment is not preceded by enough contiguous training frames of its episode.
    """
    split = np.asarray(chart.split)
    fit = [int(i) for i in w.win if i < w.ho[0] and split[i] == TRAIN]
    if not fit or fit[-1] != w.ho[0] - 1 or np.any(np.diff(fit) != 1):
        raise ValueError("GP-2D forecasts from the training frames just before the held-out segment; this clip's split has none there")
    model = fit_gp2d(frames[fit], cfg, seed, log_every)
    H = cfg.gcn_history
    long = forecast(model.forecaster, model.states[-H:], max(w.n_long, len(w.ho)))  # its start is the held-out forecast
    n_win = len(w.win)
    win = None
    if fit[0] == w.win[0] and n_win > H:  # the filmed window starts on the fitted frames
        win = np.concatenate([model.states[:H], forecast(model.forecaster, model.states[:H], n_win - H)])
    m = w.m_period
    long = long[: w.n_long]
    long_ends = np.concatenate([long[:m], long[-m:]])
    near = model.render(long[: max(len(w.ho), w.n_near)])  # the figure's stretch; its start is the held-out prediction
    out = {"held_out": near[: len(w.ho)], "near": near, "window": None if win is None else model.render(win), "long": model.render(long_ends)}
    return out, model, fit
