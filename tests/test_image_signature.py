"""The autoencoder's per-frame error as evidence for a hidden mode (lagsplat.diagnose.image_signature)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
from test_diagnose import DT, TRAIN, _chart, _linear, _run

from lagsplat.chart import Chart
from lagsplat.diagnose import diagnose_chart
from lagsplat.diagnose.image_signature import ImageError, image_error_from_chart, unencoded_oscillation
from lagsplat.timeseries import spectral_peak_frequency


def _image(ae: np.ndarray, q: np.ndarray, t: np.ndarray) -> ImageError:
    return ImageError([t], [ae], [q[:, None]])


def test_an_error_that_follows_the_encoded_state_is_no_evidence_and_an_unencoded_motion_is() -> None:
    t = np.arange(240) * DT
    rng = np.random.default_rng(0)
    f_m, f_h = 0.7, 1.63
    q = np.cos(2 * math.pi * f_m * t) * np.exp(-0.05 * t)
    qdot = np.gradient(q, DT)
    noise = 1e-4 * rng.standard_normal(len(t))
    state = 0.01 + 0.003 * q**2 + 0.002 * q**3 * qdot / 4.0 + noise  # blur and shading that go with the encoded motion
    hidden = state + 0.001 * np.cos(2 * math.pi * f_h * t + 0.3) ** 2  # a body the chart does not carry, squared in the error
    low = unencoded_oscillation(_image(state, q, t), f_h, f_m)
    high = unencoded_oscillation(_image(hidden, q, t), f_h, f_m)
    assert low["support"] < 0 < 10 < high["support"]
    assert 2 * f_h in high["frequencies_hz"] and high["n_frames"] == 240
    # a frequency on the motion's own harmonic is not tested: the state's own error lives there
    assert all(abs(f - 2 * f_m) > 0.5 / t[-1] for f in unencoded_oscillation(_image(hidden, q, t), 2 * f_m + 0.01, f_m)["frequencies_hz"])


def test_a_chart_without_a_per_frame_error_gives_none() -> None:
    ch = _chart("cart", "none", 0)  # a chart from a trajectory: ae_mse all zero
    assert image_error_from_chart(ch, TRAIN) is None
    assert image_error_from_chart(SimpleNamespace(t=ch.t, q=ch.q, ae_mse=np.full(len(ch.t), np.nan)), TRAIN) is None


def _short_mode_chart(hidden_in_image: bool) -> Chart:
    """Three periods of a pendulum with a hidden mode (one segment: a force and a mode leave the same residual);
    its per-frame error follows the encoded state, or also the hidden body's displacement."""
    run, ch = _run("pendulum", "missing_dof", 0), _chart("pendulum", "missing_dof", 0)
    seg = ch.segments(TRAIN)[0]
    n = int(round(3.0 / spectral_peak_frequency(ch.q[seg], DT) / DT))
    sl, q, I = seg[:n], ch.q[seg][:n], np.eye(1)
    second = run.second[sl] - run.second[sl].mean()
    ae = 0.01 + 0.002 * q[:, 0] ** 2 + 1e-4 * np.random.default_rng(3).standard_normal(n)
    if hidden_in_image:
        ae = ae + 0.001 * (second / np.abs(second).max()) ** 2
    return Chart(mean=np.zeros(1), W=I, W_inv=I, q=q, t=ch.t[sl] - ch.t[sl][0], split=np.full(n, TRAIN, np.int8), G_bar=I, A=I,
                 ae_mse=ae, ae_floor_train=0.0, ae_floor_held_out=0.0, height=64, width=64)  # fmt: skip


def test_the_image_tells_a_hidden_mode_from_a_periodic_force_on_a_short_clip() -> None:
    plain = _short_mode_chart(False)
    diag, _ = diagnose_chart(_linear(plain), plain)
    mode = next(f for f in diag.ranking if f.effect == "missing_dof")
    assert diag.winner == "periodic_force" and mode.interpretation["image_error_support"] < 0  # the residual alone: a force
    seen = _short_mode_chart(True)
    diag, _ = diagnose_chart(_linear(seen), seen)
    mode = diag.effects[0]
    assert diag.winner == "missing_dof" and mode.signature_support == mode.interpretation["image_error_support"] > 10
    assert "does not carry" in mode.interpretation["text"]


def test_the_image_does_not_find_a_mode_the_residual_does_not() -> None:
    ch = _chart("cart", "none", 0)
    seg = ch.segments(TRAIN)[0]
    t, q = ch.t[seg], ch.q[seg]
    ae = 0.01 + 0.001 * np.cos(2 * math.pi * 1.9 * t) ** 2  # an error that oscillates, on a clip without a mode
    I = np.eye(1)
    c = Chart(mean=np.zeros(1), W=I, W_inv=I, q=q, t=t - t[0], split=np.full(len(t), TRAIN, np.int8), G_bar=I, A=I, ae_mse=ae,
              ae_floor_train=0.0, ae_floor_held_out=0.0, height=64, width=64)  # fmt: skip
    diag, _ = diagnose_chart(_linear(c), c)
    mode = next(f for f in diag.ranking if f.effect == "missing_dof")
    assert diag.winner == "none" and mode.delta_bic < 10 and mode.signature_support == 0.0
