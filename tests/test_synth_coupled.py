"""Tests of the synthetic coupled-carts clip (lagsplat.synth.coupled_carts)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from omegaconf import OmegaConf

from lagsplat.io.clip import HELD_OUT, TRAIN, Clip, load_clip, save_clip
from lagsplat.timeseries import spectral_peak_frequency
from lagsplat.synth import GENERATORS, make_clip
from lagsplat.synth.coupled_carts import MAX_DISPLACEMENT, RAIL_Y, CoupledCarts, simulate_coupled_carts
from lagsplat.synth.coupled_carts_clip import make_coupled_carts_clip, render_coupled_carts

CONF = Path(__file__).resolve().parents[1] / "conf" / "system" / "two_carts.yaml"


@pytest.fixture(scope="module")
def clip() -> Clip:
    return make_coupled_carts_clip()


@pytest.fixture(scope="module")
def system() -> CoupledCarts:
    return CoupledCarts.from_modes((0.6, 1.0), (0.02, 0.015), (1.0, 1.5), 1.0)


def _peaks(y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sub-sample local maxima (index, value) by a parabola through 3 samples."""
    i = np.flatnonzero((y[1:-1] > y[:-2]) & (y[1:-1] >= y[2:])) + 1
    a, b, c = y[i - 1], y[i], y[i + 1]
    off = 0.5 * (a - c) / (a - 2 * b + c)
    return i + off, b - 0.25 * (a - c) * off


# ------------------------------------------------------------------ physics
def test_system_matrices_and_modes(system: CoupledCarts) -> None:
    M, K, C, Phi = system.mass, system.stiffness, system.damping, system.mode_shapes
    w = 2 * math.pi * np.array([0.6, 1.0])
    np.testing.assert_allclose(system.f_modes_hz, [0.6, 1.0], rtol=1e-12)
    np.testing.assert_allclose(Phi.T @ M @ Phi, np.eye(2), atol=1e-12)
    np.testing.assert_allclose(Phi.T @ K @ Phi, np.diag(w**2), rtol=1e-10, atol=1e-9)
    np.testing.assert_allclose(Phi.T @ C @ Phi, np.diag(2 * np.array([0.02, 0.015]) * w), atol=1e-12)
    np.testing.assert_allclose(C, C.T)
    k1, k2, k3 = system.springs
    assert k1 > 0 and k2 > 0 and k3 == pytest.approx(k1)
    np.testing.assert_allclose(K, [[k1 + k2, -k2], [-k2, k2 + k3]])
    assert np.all(Phi[0] > 0)  # sign convention
    # The first-order system's eigenvalues are -zeta w +- i w_d.
    ev = np.linalg.eigvals(system.state_matrix())
    ev = ev[ev.imag > 0]
    ev = ev[np.argsort(ev.imag)]
    np.testing.assert_allclose(-ev.real, system.decay_rates, rtol=1e-9)
    np.testing.assert_allclose(ev.imag / (2 * math.pi), system.f_modes_damped_hz, rtol=1e-9)
    # Springs round-trip: the same springs give the same truth.
    again = CoupledCarts.from_springs(system.masses, system.springs, system.zeta_modes)
    np.testing.assert_allclose(again.f_modes_hz, system.f_modes_hz, rtol=1e-12)


@pytest.mark.parametrize("masses,ratio", [((1.0, 1.0), 1.0), ((1.0, 2.0), 2.0), ((2.0, 1.0), 0.7), ((1.0, 1.5), 1.5)])
def test_from_modes_hits_requested_frequencies(masses, ratio) -> None:
    s = CoupledCarts.from_modes((0.6, 1.0), 0.02, masses, ratio)
    np.testing.assert_allclose(s.f_modes_hz, [0.6, 1.0], rtol=1e-10)
    assert min(s.springs) > 0
    assert s.springs[2] == pytest.approx(ratio * s.springs[0])


def test_ode_residual_and_modal_solution(system: CoupledCarts) -> None:
    fps, n = 200.0, 800
    x, v, t = simulate_coupled_carts(system, [0.2, -0.1], [0.3, 0.5], fps, n)
    assert x.shape == v.shape == (n, 2) and t.shape == (n,)
    np.testing.assert_allclose(t, np.arange(n) / fps)
    dt = 1 / fps
    acc = (x[2:] - 2 * x[1:-1] + x[:-2]) / dt**2
    res = acc @ system.mass.T + v[1:-1] @ system.damping.T + x[1:-1] @ system.stiffness.T
    scale = np.abs(x[1:-1] @ system.stiffness.T).max()
    assert np.abs(res).max() / scale < 1e-3
    vel = (x[2:] - x[:-2]) / (2 * dt)
    assert np.abs(vel - v[1:-1]).max() / np.abs(v).max() < 1e-3
    # Independent closed-form modal solution.
    Phi, M = system.mode_shapes, system.mass
    q0, dq0 = Phi.T @ M @ x[0], Phi.T @ M @ v[0]
    zw, wd = system.decay_rates, 2 * math.pi * system.f_modes_damped_hz
    q = np.exp(-zw * t[:, None]) * (q0 * np.cos(wd * t[:, None]) + (dq0 + zw * q0) / wd * np.sin(wd * t[:, None]))
    np.testing.assert_allclose(x, q @ Phi.T, atol=1e-12)


def test_modal_coordinates_show_the_modal_frequencies() -> None:
    light = CoupledCarts.from_modes((0.6, 1.0), 1e-4, (1.0, 1.5), 1.0)
    fps, n = 30.0, 6000  # 200 s
    x, _, _ = simulate_coupled_carts(light, [0.2, -0.1], [0.0, 0.4], fps, n)
    q = x @ (light.mode_shapes.T @ light.mass).T  # q = Phi^T M x
    for i, f in enumerate(light.f_modes_hz):
        assert spectral_peak_frequency(q[:, i], 1 / fps) == pytest.approx(f, rel=2e-3)
    # Each cart's displacement holds both modes: its spectrum peaks at one of them.
    f_x1 = spectral_peak_frequency(x[:, 0], 1 / fps)
    assert min(abs(f_x1 - f) / f for f in light.f_modes_hz) < 2e-3


def test_modal_decay_envelopes_give_zeta(system: CoupledCarts) -> None:
    fps = 30.0
    x, _, _ = simulate_coupled_carts(system, [0.2, -0.1], [0.0, 0.4], fps, 900)
    q = x @ (system.mode_shapes.T @ system.mass).T
    for i in range(2):
        idx, amp = _peaks(q[:, i])
        slope = np.polyfit(idx / fps, np.log(amp), 1)[0]
        zeta_est = -slope / system.omega[i]
        assert zeta_est == pytest.approx(system.zeta_modes[i], rel=0.03)


# --------------------------------------------------------------------- clip
def test_clip_shapes_meta_and_truth(clip: Clip) -> None:
    T = 2400
    assert clip.images.shape == (T, 64, 64, 3) and clip.images.dtype == np.uint8
    assert clip.t.dtype == np.float64
    np.testing.assert_allclose(clip.t, np.arange(T) / 30.0)
    assert np.all(np.diff(clip.t) > 0)
    assert clip.u.shape == (T, 0)
    assert clip.meta["source"] == "lagsplat.synth.coupled_carts"
    assert clip.meta["split_rule"] == "episodes"
    tr = clip.meta["truth"]
    assert {"f_modes_hz", "zeta_modes", "f_modes_damped_hz", "mass", "stiffness", "damping", "mode_shapes", "f_observed_hz"} <= set(tr)
    np.testing.assert_allclose(tr["f_modes_hz"], [0.6, 1.0], rtol=1e-10)
    assert tr["zeta_modes"] == [0.02, 0.015]
    np.testing.assert_allclose(tr["f_modes_damped_hz"], np.array([0.6, 1.0]) * np.sqrt(1 - np.array([0.02, 0.015]) ** 2))
    assert np.array(tr["mass"]).shape == np.array(tr["stiffness"]).shape == np.array(tr["damping"]).shape == (2, 2)
    # f_observed: near one of the damped modal frequencies, and what the estimator gives on the held-out cart-1 motion.
    x = np.asarray(clip.meta["x"])
    assert x.shape == (T, 2)
    assert min(abs(tr["f_observed_hz"] - f) / f for f in tr["f_modes_damped_hz"]) < 0.01
    assert tr["f_observed_hz"] == pytest.approx(spectral_peak_frequency(x[clip.held_out_idx, 0], 1 / 30.0), rel=1e-9)
    assert np.abs(x).max() == pytest.approx(0.25)
    json.dumps(clip.meta)


def test_episode_and_split_layout(clip: Clip) -> None:
    ep, split = clip.episode, clip.split
    assert ep.dtype == np.int16
    np.testing.assert_array_equal(ep, np.repeat(np.arange(4), 600))
    assert np.all(split[ep < 3] == TRAIN)
    assert np.all(split[ep == 3] == HELD_OUT)  # the held-out recording is held out entirely
    assert not np.any((split == TRAIN) & (ep == 3))
    train_segs = clip.segments(TRAIN)
    assert len(train_segs) == 3 and all(len(np.unique(ep[s])) == 1 for s in train_segs)
    (held,) = clip.segments(HELD_OUT)
    assert len(held) * clip.dt * min(clip.meta["truth"]["f_modes_hz"]) >= 8  # >= 8 slow periods
    # Every recording excites both modes comparably, from different states.
    amps = np.array([e["modal_amplitude"] for e in clip.meta["episodes"]])
    Phi = np.asarray(clip.meta["truth"]["mode_shapes"])
    peak = amps * np.abs(Phi).max(0)  # displacement each mode alone would give
    assert np.all(peak.min(1) / peak.max(1) >= 0.6 - 1e-9)
    x0 = np.array([e["x0"] for e in clip.meta["episodes"]])
    assert len({tuple(np.round(r, 6)) for r in x0}) == 4
    np.testing.assert_allclose(np.asarray(clip.meta["x"])[::600], x0)


def test_carts_visible_and_tracking(clip: Clip) -> None:
    img = clip.images.astype(np.float32) / 255.0
    x = np.asarray(clip.meta["x"])
    W = img.shape[2]
    xs = np.arange(W) + 0.5
    ys = np.arange(img.shape[1]) + 0.5
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    for j, mask in enumerate([r - np.maximum(g, b) > 0.3, b - np.maximum(r, g) > 0.3]):
        w = mask.astype(float)
        assert np.all(w.sum((1, 2)) > 10)
        cx = (w * xs[None, None, :]).sum((1, 2)) / w.sum((1, 2))
        cy = (w * ys[None, :, None]).sum((1, 2)) / w.sum((1, 2))
        assert np.corrcoef(cx, x[:, j])[0, 1] > 0.99
        slope = np.polyfit(x[:, j], cx, 1)[0]
        assert slope == pytest.approx(W, rel=0.03)  # x in frame widths
        half = img.shape[1] / 2
        assert np.all(cy < half) if j == 0 else np.all(cy > half)  # cart 1 upper, cart 2 lower half
    corner = img[0, :6, 6:20]
    assert corner.mean() > 0.7 and corner.std() > 0.001  # light, faintly textured background


def test_render_sizes_and_limits() -> None:
    for size in [(64, 64), (96, 48), (40, 80)]:
        W, H = size
        fr = render_coupled_carts([[-MAX_DISPLACEMENT, MAX_DISPLACEMENT], [0.0, 0.0]], size=size)
        assert fr.shape == (2, H, W, 3)
        sat = fr.astype(float).max(-1) - fr.astype(float).min(-1)
        for f in sat:
            rows, cols = np.nonzero(f > 100)
            assert rows.min() > 0 and rows.max() < H - 1 and cols.min() > 0 and cols.max() < W - 1
    assert RAIL_Y[0] < 0.5 < RAIL_Y[1]
    with pytest.raises(ValueError, match="MAX_DISPLACEMENT"):
        render_coupled_carts([[0.5, 0.0]])
    with pytest.raises(ValueError, match=r"\[T, 2\]"):
        render_coupled_carts([0.1, 0.2])
    with pytest.raises(ValueError, match="NaN"):
        render_coupled_carts([[np.nan, 0.0]])
    with pytest.raises(ValueError, match="size"):
        render_coupled_carts([[0.0, 0.0]], size=(8, 8))


def test_deterministic_and_roundtrip(tmp_path) -> None:
    a = make_coupled_carts_clip(duration_s=2.0, n_episodes=2, seed=3)
    b = make_coupled_carts_clip(duration_s=2.0, n_episodes=2, seed=3)
    assert a.images.tobytes() == b.images.tobytes() and a.meta == b.meta
    c = make_coupled_carts_clip(duration_s=2.0, n_episodes=2, seed=4)
    assert c.meta["x"] != a.meta["x"]
    assert c.meta["truth"]["f_modes_hz"] == a.meta["truth"]["f_modes_hz"]
    back = load_clip(save_clip(tmp_path / "clip.npz", a))
    assert back.images.tobytes() == a.images.tobytes()
    np.testing.assert_array_equal(back.episode, a.episode)
    assert back.meta == json.loads(json.dumps(a.meta))


def test_single_episode_uses_train_fraction() -> None:
    c = make_coupled_carts_clip(duration_s=4.0, n_episodes=1, train_fraction=0.5, size=(32, 32))
    assert c.meta["split_rule"] == "train_fraction"
    assert np.all(c.episode == 0)
    assert np.all(c.split[:60] == TRAIN) and np.all(c.split[60:] == HELD_OUT)
    with pytest.raises(ValueError, match="train_fraction"):
        make_coupled_carts_clip(duration_s=4.0, n_episodes=1)
    # Several episodes: train_fraction is ignored, the episodes define the split.
    d = make_coupled_carts_clip(duration_s=1.0, n_episodes=3, train_fraction=0.9, size=(32, 32))
    assert d.meta["split_rule"] == "episodes"
    np.testing.assert_array_equal(d.split, np.repeat([TRAIN, TRAIN, HELD_OUT], 30))


@pytest.mark.parametrize(
    "kwargs,match",
    [
        ({"f_modes_hz": (1.0, 0.6)}, "ascending"),
        ({"f_modes_hz": (0.6, 0.6)}, "distinct"),
        ({"zeta": 1.2}, "zeta"),
        ({"zeta": (0.02, 0.02, 0.02)}, "zeta"),
        ({"masses": (1.0, -1.0)}, "masses"),
        ({"masses": (1.0, 1.5), "wall_ratio": 0.5}, "wall_ratio"),
        ({"amplitude": 0.5}, "amplitude"),
        ({"n_episodes": 0}, "n_episodes"),
        ({"n_episodes": 3, "held_out_episodes": 3}, "held_out_episodes"),
        ({"n_episodes": 3, "held_out_episodes": 0}, "held_out_episodes"),
        ({"train_fraction": 1.5}, "train_fraction"),
        ({"duration_s": 0.1}, "duration_s"),
        ({"fps": 0.0}, "fps"),
        ({"size": (8, 8)}, "size"),
    ],
)
def test_bad_arguments(kwargs, match) -> None:
    with pytest.raises(ValueError, match=match):
        make_coupled_carts_clip(**{"duration_s": 1.0, **kwargs})


def test_bad_simulator_arguments(system: CoupledCarts) -> None:
    with pytest.raises(ValueError, match="x0 and v0"):
        simulate_coupled_carts(system, [0.1], [0.0, 0.0], 30.0, 10)
    with pytest.raises(ValueError, match="n_frames"):
        simulate_coupled_carts(system, [0.1, 0.0], [0.0, 0.0], 30.0, 1)
    with pytest.raises(ValueError, match="CoupledCarts"):
        simulate_coupled_carts("carts", [0.1, 0.0], [0.0, 0.0], 30.0, 10)
    with pytest.raises(ValueError, match="k2 > 0"):
        CoupledCarts.from_springs((1.0, 1.0), (10.0, 0.0, 10.0))


def test_make_clip_with_conf_system_block(clip: Clip) -> None:
    assert GENERATORS["coupled_carts"] is make_coupled_carts_clip
    cfg = OmegaConf.load(CONF)
    assert cfg.system.d == 2 and cfg.system.name == "two_carts"
    assert "split" not in cfg.system
    c = make_clip(cfg.system)
    assert c.images.tobytes() == clip.images.tobytes()  # the conf file spells out the defaults
    assert c.meta == clip.meta
    # A split.train_fraction from elsewhere does not override the episode split.
    plain = OmegaConf.to_container(cfg.system, resolve=True)
    plain["source"]["params"].update(duration_s=1.0, size=[32, 32])
    plain["split"] = {"train_fraction": 0.6}
    d = make_clip(plain)
    np.testing.assert_array_equal(d.split, np.repeat([TRAIN, TRAIN, TRAIN, HELD_OUT], 30))
    plain["source"]["params"]["n_episodes"] = 1
    e = make_clip(plain)
    assert len(e.train_idx) == 18 and e.meta["split_rule"] == "train_fraction"
