"""Tests of the embedded synthetic clip (lagsplat.synth)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from omegaconf import OmegaConf

from lagsplat.io.clip import HELD_OUT, TRAIN, Clip, load_clip, save_clip
from lagsplat.synth import make_clip
from lagsplat.synth.pendulum import make_pendulum_clip, render_pendulum, simulate_pendulum


@pytest.fixture(scope="module")
def clip() -> Clip:
    return make_pendulum_clip()


def _peaks(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sub-sample local maxima (index, value) by a parabola through 3 samples."""
    i = np.flatnonzero((theta[1:-1] > theta[:-2]) & (theta[1:-1] >= theta[2:])) + 1
    a, b, c = theta[i - 1], theta[i], theta[i + 1]
    den = a - 2 * b + c
    off = 0.5 * (a - c) / den
    return i + off, b - 0.25 * (a - c) * off


def test_shapes_dtypes_and_split(clip: Clip) -> None:
    T = 600
    assert clip.images.shape == (T, 64, 64, 3)
    assert clip.images.dtype == np.uint8
    assert clip.t.shape == (T,) and clip.t.dtype == np.float64
    np.testing.assert_allclose(clip.t, np.arange(T) / 30.0)
    assert clip.u.shape == (T, 0)
    n_train = int(0.6 * T)
    assert np.all(clip.split[:n_train] == TRAIN) and np.all(clip.split[n_train:] == HELD_OUT)
    assert clip.meta["source"] == "lagsplat.synth.pendulum"
    assert len(clip.meta["theta"]) == T
    assert set(clip.meta["truth"]) == {
        "f_natural_hz",
        "zeta",
        "f_damped_small_angle_hz",
        "f_observed_hz",
        "theta0_rad",
        "decay_rate_per_s",
    }
    assert clip.meta["params"]["size"] == [64, 64]
    json.dumps(clip.meta)  # serialisable
    assert clip.meta["theta"][0] == pytest.approx(math.radians(20.0))


def test_background_not_uniform_and_bob_visible(clip: Clip) -> None:
    img = clip.images[0].astype(float)
    corner = img[:8, :8]
    assert corner.std() > 0.3  # faint texture, not a flat fill
    assert corner.mean() > 180  # light background
    sat = img.max(-1) - img.min(-1)
    assert sat.max() > 120  # saturated bob colours


def test_deterministic(tmp_path) -> None:
    a = make_pendulum_clip(duration_s=2.0, seed=3)
    b = make_pendulum_clip(duration_s=2.0, seed=3)
    assert a.images.tobytes() == b.images.tobytes()
    assert a.meta == b.meta
    c = make_pendulum_clip(duration_s=2.0, seed=4)
    assert c.images.tobytes() != a.images.tobytes()
    assert c.meta["theta"] == a.meta["theta"]  # the seed only changes the background
    path = save_clip(tmp_path / "clip.npz", a)
    back = load_clip(path)
    assert back.images.tobytes() == a.images.tobytes()
    assert back.meta == json.loads(json.dumps(a.meta))


def test_bob_centroid_tracks_sin_theta(clip: Clip) -> None:
    img = clip.images.astype(float) / 255.0
    sat = img.max(-1) - img.min(-1)  # only the bob is strongly coloured
    w = np.where(sat > 0.3, sat, 0.0)
    xs = np.arange(img.shape[2]) + 0.5
    cx = (w * xs[None, None, :]).sum((1, 2)) / w.sum((1, 2))
    s = np.sin(np.asarray(clip.meta["theta"]))
    assert np.corrcoef(cx, s)[0, 1] > 0.99
    assert np.all(cx[s > 0.1] > 32) and np.all(cx[s < -0.1] < 32)  # positive theta: to the right


def test_bob_inside_frame_at_large_angles() -> None:
    for size in [(64, 64), (48, 36), (128, 96)]:
        W, H = size
        frames = render_pendulum(np.radians([-25.0, 25.0]), size=size)
        assert frames.shape == (2, H, W, 3)
        sat = frames.astype(float).max(-1) - frames.astype(float).min(-1)
        for f in sat:
            mask = f > 60
            assert mask.any()
            rows, cols = np.nonzero(mask)
            assert rows.min() > 0 and rows.max() < H - 1
            assert cols.min() > 0 and cols.max() < W - 1


def test_observed_frequency_close_to_small_angle(clip: Clip) -> None:
    tr = clip.meta["truth"]
    assert tr["f_damped_small_angle_hz"] == pytest.approx(0.8 * math.sqrt(1 - 0.02**2))
    assert abs(tr["f_observed_hz"] - tr["f_damped_small_angle_hz"]) / tr["f_damped_small_angle_hz"] < 0.01


def test_held_out_covers_two_periods(clip: Clip) -> None:
    n_held = len(clip.held_out_idx)
    periods = n_held * clip.dt * clip.meta["truth"]["f_damped_small_angle_hz"]
    assert periods >= 2.0


def test_damping_envelope(clip: Clip) -> None:
    theta = np.asarray(clip.meta["theta"])
    idx, amp = _peaks(theta)
    t_peak = idx / 30.0
    slope = np.polyfit(t_peak, np.log(amp), 1)[0]
    rate = clip.meta["truth"]["decay_rate_per_s"]
    assert rate == pytest.approx(0.02 * 2 * math.pi * 0.8)
    assert abs(-slope - rate) / rate < 0.03


def test_simulator_small_angle_matches_linear_solution() -> None:
    f_n, zeta, fps = 1.1, 0.05, 50.0
    theta, t = simulate_pendulum(f_n, zeta, 1e-4, fps, 300)
    w0 = 2 * math.pi * f_n
    wd = w0 * math.sqrt(1 - zeta**2)
    lin = 1e-4 * np.exp(-zeta * w0 * t) * (np.cos(wd * t) + zeta * w0 / wd * np.sin(wd * t))
    np.testing.assert_allclose(theta, lin, atol=1e-4 * 1e-5)
    with pytest.raises(ValueError):
        simulate_pendulum(1.0, 1.5, 0.1, 30.0, 10)


def test_make_clip_from_config() -> None:
    cfg = {"source": {"synth": "pendulum", "params": {"duration_s": 2.0, "seed": 1}}}
    a = make_clip(cfg)
    assert a.n_frames == 60
    b = make_clip(OmegaConf.create(cfg))
    assert a.images.tobytes() == b.images.tobytes()
    c = make_clip(
        OmegaConf.create(
            {
                "source": {"synth": "pendulum", "params": {"duration_s": 2.0, "train_fraction": 0.6}},
                "split": {"train_fraction": 0.5},
                "resize": [48, 40],
            }
        )
    )
    assert c.images.shape == (60, 40, 48, 3)
    assert len(c.train_idx) == 30
    assert c.meta["params"]["size"] == [48, 40]
    with pytest.raises(ValueError, match="doublependulum"):
        make_clip({"source": {"synth": "doublependulum"}})
    with pytest.raises(ValueError, match="bogus"):
        make_clip({"source": {"synth": "pendulum", "params": {"bogus": 1}}})
    with pytest.raises(ValueError, match="train_fraction"):
        make_clip({"source": {"synth": "pendulum", "params": {"train_fraction": 1.5}}})


def test_banded_wide_rod_and_counter_arm() -> None:
    """The force ground truth's pendulum: wide banded rod and a counter-arm above the pivot."""
    from lagsplat.synth.pendulum import PIVOT_Y, render_pendulum

    plain = render_pendulum([0.0], size=(64, 64))[0].astype(float)
    wide = render_pendulum([0.0], size=(64, 64), rod_width=0.1, rod_bands=6, rod_above=0.1)[0].astype(float)
    row = int(0.45 * 64)  # on the rod, between pivot and bob
    dark = lambda im: (im[row].mean(-1) < 150).sum()  # noqa: E731
    assert dark(plain) <= 4 and 5 <= (np.abs(wide[row] - plain[row]).sum(-1) > 60).sum() <= 9
    above = int((PIVOT_Y - 0.07) * 64)  # above the pivot: only the counter-arm is there
    assert np.abs(wide[above] - plain[above]).max() > 60 and np.abs(plain[above] - plain[above, :5].mean(0)).max() < 40
    # the bands alternate colours along the rod
    col = wide[int(0.2 * 64) : int(0.7 * 64), 32]
    assert len(np.unique((col.mean(-1) > 120).astype(int))) == 2
    # stripes across the width: a checkerboard, so a row across the rod shows both colours
    # (motion across the rod is seen along the rod's axis, not only at its two edges)
    checker = render_pendulum([0.0], size=(64, 64), rod_width=0.1, rod_bands=6, rod_above=0.1, rod_stripes=2)[0].astype(float)
    light = lambda im, y: (im[y, 29:35].mean(-1) > 120).astype(int)  # noqa: E731  (pixels inside the rod, x = 28.8 .. 35.2)
    assert all(len(np.unique(light(wide, y))) == 1 for y in (13, 21, 28, 35))  # bands only (rows inside bands): one colour per row
    assert all(len(np.unique(light(checker, y))) == 2 for y in (13, 21, 28, 35))
    assert not np.any(light(checker, 28)[:3] == light(checker, 28)[3:])  # left and right halves swap
    assert np.array_equal(render_pendulum([0.3], rod_width=0.1, rod_bands=6, rod_stripes=1), render_pendulum([0.3], rod_width=0.1, rod_bands=6))
    with pytest.raises(ValueError, match="rod_stripes"):
        render_pendulum([0.0], rod_stripes=-1)
    with pytest.raises(ValueError, match="rod_width"):
        render_pendulum([0.0], rod_width=0.5)
    with pytest.raises(ValueError, match="rod_above"):
        render_pendulum([0.0], rod_above=0.2)
