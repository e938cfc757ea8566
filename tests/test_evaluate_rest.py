"""Held-out frames at rest (lagsplat.evaluate.rest): a motion stopped by dry friction is scored by its rest, not by noise."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from lagsplat.chart import Chart
from lagsplat.evaluate import EvalConfig, evaluate
from lagsplat.io.clip import HELD_OUT, TRAIN, Clip
from lagsplat.viewer.synthetic import synthetic_pendulum

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _stopping(rest: float, stop_s: float = 4.0, seconds: float = 10.0, fps: float = 30.0):
    """``(ae, chart, clip, model)``: a swing about ``rest`` whose amplitude falls linearly to 0 at ``stop_s``, then still; last 40 % held out."""
    torch.manual_seed(0)
    ae, chart0, model = synthetic_pendulum(size=32, seconds=seconds, n_background=4)
    t = chart0.t
    amp = 0.3 * np.clip(1 - t / stop_s, 0, None)  # dry friction: a linear envelope, then at rest
    rng = np.random.default_rng(0)
    q = (rest + amp * np.cos(2 * math.pi * 0.8 * t) + 2e-4 * rng.standard_normal(len(t)))[:, None]
    split = np.where(np.arange(len(t)) < int(0.6 * len(t)), TRAIN, HELD_OUT).astype(np.int8)
    with torch.no_grad():
        rec = torch.cat([ae.decode(torch.as_tensor(q[i : i + 64], dtype=torch.float32)) for i in range(0, len(q), 64)]).permute(0, 2, 3, 1).numpy()
    images = np.clip(np.round(255 * rec), 0, 255).astype(np.uint8)
    ae_mse = ((images / 255.0 - rec) ** 2).mean(axis=(1, 2, 3)) + 1e-6
    I = np.eye(1)
    chart = Chart(mean=np.zeros(1), W=I, W_inv=I, q=q, t=t, split=split, G_bar=I * 1e-3, A=I, ae_mse=ae_mse,
                  ae_floor_train=float(ae_mse[split == TRAIN].mean()), ae_floor_held_out=float(ae_mse[split == HELD_OUT].mean()), height=32, width=32)  # fmt: skip
    return ae, chart, Clip(images=images, t=t, split=split, meta={"source": "test"}), model


def test_a_motion_at_rest_in_the_held_out_frames_is_scored_by_its_rest() -> None:
    ae, chart, clip, model = _stopping(rest=0.06)  # sticks off the model's rest state (q = 0), as dry friction does
    m = evaluate(clip, ae, chart, model, EvalConfig(n_windows=8))
    assert m["held_out_at_rest"]["value"] == 1
    assert all(m[k]["value"] is None for k in ("eps_freq", "eps_q", "f_sim_hz", "f_enc_hz"))  # no NRMSE over a still segment
    assert m["rest_time_s"]["value"] == pytest.approx(4.0, abs=0.5)
    assert m["rest_position"]["value"][0] == pytest.approx(0.06, abs=0.005)
    off = m["eps_rest"]["value"]
    assert off > 0.1  # a model without friction leaves the off-centre rest and swings about its own
    ae, chart, clip, model = _stopping(rest=0.0)  # at the model's rest state: it stays there
    m0 = evaluate(clip, ae, chart, model, EvalConfig(n_windows=8))
    assert m0["eps_rest"]["value"] < 0.1 * off and m0["model_rest_time_s"]["value"] is not None
    assert np.isfinite(m0["eps_I_over_AE"]["value"])


def test_a_motion_that_still_moves_keeps_the_oscillation_metrics() -> None:
    ae, chart, clip, model = _stopping(rest=0.0, stop_s=40.0)  # still swinging in the held-out frames
    m = evaluate(clip, ae, chart, model, EvalConfig(n_windows=8))
    assert "held_out_at_rest" not in m and m["eps_q"]["value"] is not None and m["eps_freq"]["value"] < 0.2


def test_a_motion_that_comes_to_rest_early_in_the_held_out_frames_is_scored_by_its_rest() -> None:
    # held out from 6 s; the swing (0.8 Hz) dies out by 7.5 s: under two periods move there, then 2.5 s at rest
    ae, chart, clip, model = _stopping(rest=0.06, stop_s=7.5)
    m = evaluate(clip, ae, chart, model, EvalConfig(n_windows=8))
    assert m["held_out_at_rest"]["value"] == 1 and m["eps_q"]["value"] is None
    assert 6.2 < m["rest_time_s"]["value"] <= 7.5
    assert m["rest_position"]["value"][0] == pytest.approx(0.06, abs=0.005)
    assert m["eps_rest"]["value"] > 0.1  # the frictionless model swings on about q = 0
