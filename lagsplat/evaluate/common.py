"""What the evaluation protocols share: the ``metrics.json`` entry and the decoded-image error (paper §4.1)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import torch
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

from lagsplat.chart import Chart
from lagsplat.models.autoencoder import AutoEncoder, frames_to_tensor

__all__ = ["metric_entry", "metric_value", "finite_number", "decode_mse", "decoded_image_errors"]


def metric_entry(value: Any, definition: str, horizon: str = "", units: str = "") -> dict:
    """One entry of ``metrics.json``: ``{value, definition, horizon, units}``; NumPy scalars become floats."""
    v = float(value) if isinstance(value, (float, int, np.floating, np.integer)) else value
    return {"value": v, "definition": definition, "horizon": horizon, "units": units}


def metric_value(m: Mapping[str, Any] | None, key: str) -> Any:
    """The value of entry ``key`` of a ``metrics`` block (a :func:`metric_entry`, or a bare value); ``None`` when absent."""
    e = (m or {}).get(key)
    return e.get("value") if isinstance(e, Mapping) else e


def finite_number(x: Any) -> float | None:
    """``x`` as a float when it is a finite number, else ``None`` (a metric a run did not have)."""
    return float(x) if isinstance(x, (int, float)) and math.isfinite(float(x)) else None


def _decoded(ae: AutoEncoder, chart: Chart, q_pred: np.ndarray, batch: int):
    """``(i, decode(q_pred[i : i + batch]))`` per batch: the states' images ``[b, 3, H, W]`` in [0, 1]."""
    for i in range(0, len(q_pred), batch):
        yield i, ae.decode(chart.to_raw(torch.as_tensor(q_pred[i : i + batch], dtype=torch.float32)))


def _mse(rec: torch.Tensor, frames: np.ndarray) -> np.ndarray:
    """Per-image MSE of ``rec [b, 3, H, W]`` against uint8 ``frames [b, H, W, 3]``."""
    return ((rec - frames_to_tensor(frames)) ** 2).mean(dim=(1, 2, 3)).numpy()


@torch.no_grad()
def decode_mse(ae: AutoEncoder, chart: Chart, q_pred: np.ndarray, frames: np.ndarray, batch: int) -> np.ndarray:
    """Per-state image MSE of decoded ``q_pred [M,d]`` against uint8 ``frames [M,H,W,3]``."""
    out = np.empty(len(q_pred))
    for i, rec in _decoded(ae, chart, q_pred, batch):
        out[i : i + batch] = _mse(rec, frames[i : i + batch])
    return out


@torch.no_grad()
def decoded_image_errors(ae: AutoEncoder, chart: Chart, q_pred: np.ndarray, frames: np.ndarray, batch: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-state MSE, PSNR (dB) and SSIM of decoded ``q_pred [M,d]`` against uint8 ``frames [M,H,W,3]``, each
    state decoded once.

    The MSE as :func:`decode_mse` (paper §4.1, ``eps_I``); scikit-image's ``peak_signal_noise_ratio`` and
    ``structural_similarity`` (Gaussian-free 7 x 7 window, colour channels averaged, ``data_range`` 1)
    on pixels in [0, 1] at the training resolution: the image-quality numbers the field reports next to
    the MSE. A frame decoded exactly gives ``inf`` dB; SSIM is NaN on images under 3 px a side (no window fits).

    Returns:
        ``(mse [M], psnr [M], ssim [M])``, float64.
    """
    mse, psnr, ssim = np.empty(len(q_pred)), np.empty(len(q_pred)), np.empty(len(q_pred))
    for i, rec_t in _decoded(ae, chart, q_pred, batch):
        mse[i : i + batch] = _mse(rec_t, frames[i : i + batch])
        rec = rec_t.permute(0, 2, 3, 1).double().numpy()
        x = frames[i : i + batch].astype(np.float64) / 255.0
        for j in range(len(rec)):
            with np.errstate(divide="ignore"):  # an exact decode: inf dB, left out of the mean by the caller
                psnr[i + j] = peak_signal_noise_ratio(x[j], rec[j], data_range=1.0)
            side = min(x.shape[1:3])
            win = min(7, side if side % 2 else side - 1)  # odd, at most the image side
            ssim[i + j] = structural_similarity(x[j], rec[j], data_range=1.0, channel_axis=-1, win_size=win) if win >= 3 else np.nan
    return mse, psnr, ssim
