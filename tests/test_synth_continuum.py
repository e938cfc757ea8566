"""Tests of the offline soft-robot surrogate (lagsplat.synth.continuum_robot)."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import root

import lagsplat.synth.continuum_robot as cr
from lagsplat.io.npz import read_npz
from lagsplat.timeseries import spectral_peak_frequency

CLIP_S = 40.0  # short clips for the file tests


@pytest.fixture(scope="module")
def clips(tmp_path_factory):
    """One written clip per variant: {n_segments: (path, meta)}."""
    root_dir = tmp_path_factory.mktemp("robot")
    out = {}
    for n in (1, 2):
        path = root_dir / f"robot_{n}seg.npz"
        out[n] = (path, cr.write_robot_npz(path, n, duration_s=CLIP_S, seed=3))
    return out


def _tip(robot: cr.ContinuumRobot, q: np.ndarray) -> np.ndarray:
    """Complex tip position (m, y down) per frame."""
    r, _ = robot.backbone(q, 4)
    return r[..., -1]


# ------------------------------------------------------------------ physics
@pytest.mark.parametrize("n", [1, 2])
def test_kinematics_jacobian_and_convective_term_match_finite_differences(n):
    robot = cr.ContinuumRobot.default(n)
    rng = np.random.default_rng(1)
    q = rng.uniform(-1.0, 1.0, robot.d) * np.tile([1.2, 0.15], n)
    v = rng.normal(size=robot.d) * np.tile([2.0, 0.3], n)
    r, J, a = robot.kinematics(q, v)
    h = 1e-5
    J_fd = np.stack([(robot.kinematics(q + h * e)[0] - robot.kinematics(q - h * e)[0]) / (2 * h) for e in np.eye(robot.d)], axis=1)
    np.testing.assert_allclose(J, J_fd, atol=1e-8)
    h2 = 1e-4  # second directional derivative along v: Jdot v
    a_fd = (robot.kinematics(q + h2 * v)[0] - 2 * r + robot.kinematics(q - h2 * v)[0]) / h2**2
    np.testing.assert_allclose(a, a_fd, atol=1e-5 * np.abs(a).max())
    # The lumped-mass nodes lie on the rendered PCC backbone.
    bb, _ = robot.backbone(q, robot.n_nodes)
    np.testing.assert_allclose(bb[1:], r, atol=1e-13)


@pytest.mark.parametrize("n", [1, 2])
def test_energy_is_conserved_without_damping_and_pressure(n):
    robot = cr.ContinuumRobot.default(n)
    q = np.tile([0.9, 0.08], n)
    v = np.tile([-1.5, 0.4], n)
    E0 = robot.kinetic_energy(q, v) + robot.potential(q)
    zero = np.zeros(2 * n)
    h = 2e-4
    f = lambda y: np.concatenate([y[robot.d:], robot.acceleration(y[: robot.d], y[robot.d:], zero, damping=False)])
    y = np.concatenate([q, v])
    moved = 0.0
    for _ in range(1500):  # 0.3 s, large nonlinear swing
        k1 = f(y)
        k2 = f(y + 0.5 * h * k1)
        k3 = f(y + 0.5 * h * k2)
        k4 = f(y + h * k3)
        y = y + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        moved = max(moved, abs(y[0] - q[0]))
    E1 = robot.kinetic_energy(y[: robot.d], y[robot.d:]) + robot.potential(y[: robot.d])
    assert moved > 0.5  # it really swung
    assert abs(E1 - E0) < 1e-8 * abs(E0)  # RK4 error only (~6e-10); dropping the convective term drifts by ~13 %


@pytest.mark.parametrize("n", [1, 2])
def test_linearised_frequencies_match_the_simulated_tail(n):
    robot = cr.ContinuumRobot.default(n)
    modal = robot.modal
    # Rayleigh damping: the two lowest modes have the requested damping ratios.
    np.testing.assert_allclose(modal.zeta[:2], robot.zeta, rtol=1e-6)
    assert np.all(np.diff(modal.f_natural_hz) > 0)
    sched = cr.PressureSchedule.random(n, cr.DEFAULT_DURATION_S, seed=0)
    states, _ = cr.simulate_frames(robot, sched, cr.n_frames_for(cr.DEFAULT_DURATION_S))
    start = math.ceil(sched.tail_start_s / cr.DT)
    tip = _tip(robot, states[start:, : robot.d])
    assert np.abs(tip.real).max() > 1e-3  # the release left it ringing
    f_bend = spectral_peak_frequency(tip.real, cr.DT)  # lowest mode dominates the sideways motion
    assert abs(f_bend / modal.f_natural_hz[0] - 1) < 0.02
    if n == 1:  # the extension mode shows in the vertical motion (released faster than its period)
        f_axial = spectral_peak_frequency(tip.imag[:300], cr.DT)
        assert abs(f_axial / modal.f_natural_hz[1] - 1) < 0.02
    # The default robots ring near the real robots' free frequencies (paper Sec. 4.4).
    assert modal.f_natural_hz[0] == pytest.approx(4.63 if n == 1 else 1.566, rel=0.03)


@pytest.mark.parametrize("n", [1, 2])
def test_pressure_difference_sign_sets_the_bending_direction(n):
    robot = cr.ContinuumRobot.default(n)
    for sign in (1.0, -1.0):
        P = np.tile([0.45 + 0.3 * sign, 0.45 - 0.3 * sign], n)  # p_left - p_right = 0.6 sign
        q_eq = root(lambda q, P=P: robot.grad_potential(q) - robot.actuation_matrix @ P, robot.modal.q_rest, tol=1e-12).x
        assert np.all(np.sign(q_eq[0::2]) == sign)
        assert np.all(q_eq[1::2] > robot.modal.q_rest[1::2])  # the sum extends
        # Dynamics under constant pressure settle there; the tip moves to that side.
        states, _ = cr.simulate_frames(robot, lambda t, P=P: np.tile(P, (len(t), 1)), 600)
        np.testing.assert_allclose(states[-1, : robot.d], q_eq, atol=2e-2)
        assert np.sign(_tip(robot, states[-1, : robot.d]).real) == sign
        # In the picture, the lower half of the arm sits on that side of the centre.
        img = cr.render_continuum_robot(q_eq[None], robot)[0].astype(float).mean(axis=-1)
        lower = img[16:] - np.median(img)
        x = np.arange(32) + 0.5
        cx = float((lower.clip(0).sum(axis=0) * x).sum() / lower.clip(0).sum())
        assert np.sign(cx - 16.0) == sign


def test_pressures_in_band_nonnegative_and_zero_in_head_rests_and_tail():
    sched = cr.PressureSchedule.random(2, 150.0, seed=5)
    t = np.arange(cr.n_frames_for(150.0)) * cr.DT
    P = sched(t)
    assert P.shape == (t.size, 4)
    assert P.min() >= 0.0 and P.max() <= sched.p_max
    assert P.max() > 0.6 * sched.p_max  # driven over much of the range
    assert np.all(P[t <= sched.head_s] == 0) and np.all(P[t >= sched.tail_start_s] == 0)
    assert len(sched.rests) == 2
    for t_rel, t_up in sched.rests:
        assert t_up < 0.8 * 150.0  # free motion inside the training split
        assert np.all(P[(t >= t_rel + sched.release_s) & (t <= t_up)] == 0)
    assert sched.tail_start_s - sched.release_s >= 0.8 * 150.0
    # The random carrier lies in 0.04-2 Hz (a long window resolves the band edge).
    tl = np.arange(2**16) * cr.DT
    for c in range(4):
        s = sched.carrier(tl)[:, c]
        F = np.abs(np.fft.rfft((s - s.mean()) * np.hanning(s.size))) ** 2
        f = np.fft.rfftfreq(s.size, cr.DT)
        out = F[(f < 0.035) | (f > 2.05)].sum() / F.sum()
        assert out < 1e-3
    # Where the clip is fully driven, nothing above the band: energy above 2.2 Hz is tiny.
    full = (sched.gate(t) == 1.0)
    edges = np.flatnonzero(np.diff(full.astype(int)))
    a, b = edges[0] + 1, edges[1] + 1
    assert (b - a) * cr.DT > 10
    for c in range(4):
        x = P[a:b, c] - P[a:b, c].mean()
        F = np.abs(np.fft.rfft(x * np.hanning(x.size))) ** 2
        f = np.fft.rfftfreq(x.size, cr.DT)
        assert F[f > 2.2].sum() / F.sum() < 1e-3
    # Chambers are independent draws.
    assert abs(np.corrcoef(P[a:b, 0], P[a:b, 1])[0, 1]) < 0.9


# ------------------------------------------------------------------ file
@pytest.mark.parametrize("n", [1, 2])
def test_npz_layout_and_sidecar(clips, n):
    path, meta = clips[n]
    keys = ["p1", "p2"] if n == 1 else ["p1", "p2", "p3", "p4"]
    with np.load(path, allow_pickle=False) as z:
        assert sorted(z.files) == sorted(["images", *keys])
        im = z["images"]
        P = np.stack([z[k] for k in keys], axis=1)
        assert all(z[k].dtype == np.float32 and z[k].shape == (im.shape[0],) for k in keys)
    T = round(CLIP_S * cr.FPS)
    assert im.shape == (T, 3, 32, 32) and im.dtype == np.float32
    assert im.min() >= 0.0 and im.max() <= 1.0
    assert np.abs(im * 255.0 - np.round(im * 255.0)).max() < 1e-3
    assert im.std(axis=0).max() > 0.05  # the arm moves

    side = json.loads(Path(str(path) + ".json").read_text())
    assert side == json.loads(json.dumps(meta))
    for k in ("n_segments", "fps", "dt", "n_frames", "f_natural_hz", "zeta", "tail_start_frame", "head_frames", "seed", "params"):
        assert k in side
    assert side["n_segments"] == n and side["n_frames"] == T and side["seed"] == 3
    assert side["dt"] == pytest.approx(1001 / 60000, abs=1e-15) and side["fps"] == pytest.approx(59.94, abs=1e-3)
    assert len(side["f_natural_hz"]) == 2 * n and side["f_natural_hz"] == sorted(side["f_natural_hz"])
    np.testing.assert_allclose(side["f_natural_hz"], cr.ContinuumRobot.default(n).modal.f_natural_hz)
    assert all(0 < z < 1 for z in side["zeta"])
    # Head: pressures zero and the robot still; tail: zero pressure to the end, in the held-out 20 %.
    h, ts = side["head_frames"], side["tail_start_frame"]
    assert h > 30 and np.all(P[:h] == 0) and np.any(P[h] != 0)
    assert np.all(im[:h] == im[0])
    assert np.all(P[ts:] == 0) and np.any(P[ts - 1] != 0)
    assert ts >= int(0.8 * T) == side["n_train_frames"]
    assert T - ts > 8 * cr.FPS / side["f_natural_hz"][0]  # >= 8 periods of the lowest mode
    for a, b in side["rest_frames"]:  # zero-pressure intervals inside the training split
        assert b <= int(0.8 * T) and np.all(P[a:b] == 0)
    assert side["params"]["robot"]["n_segments"] == n


@pytest.mark.parametrize("n", [1, 2])
def test_repository_reader_reads_the_file(clips, n):
    path, meta = clips[n]
    frames, t, u, names, info = read_npz(path, dt=meta["dt"])
    assert frames.shape == (meta["n_frames"], 32, 32, 3) and frames.dtype == np.uint8
    assert names == (["p1", "p2"] if n == 1 else ["p1", "p2", "p3", "p4"])
    assert info["fps"] == pytest.approx(59.94, abs=1e-3)
    np.testing.assert_allclose(np.diff(t), 1001 / 60000)
    with np.load(path) as z:
        np.testing.assert_array_equal(u, np.stack([z[k] for k in names], axis=1))
        np.testing.assert_array_equal(frames, np.rint(np.moveaxis(z["images"], 1, -1) * 255).astype(np.uint8))
    # The fps the benchmark states agrees with dt (the reader rejects a mismatch above 1e-6).
    read_npz(path, fps=meta["fps"], dt=meta["dt"], stop=4)


def test_reproducible_with_a_seed(tmp_path):
    a = cr.write_robot_npz(tmp_path / "a.npz", 2, duration_s=20.0, seed=7)
    b = cr.write_robot_npz(tmp_path / "b.npz", 2, duration_s=20.0, seed=7)
    assert {k: v for k, v in a.items() if k != "npz"} == {k: v for k, v in b.items() if k != "npz"}
    with np.load(tmp_path / "a.npz") as za, np.load(tmp_path / "b.npz") as zb:
        for k in za.files:
            np.testing.assert_array_equal(za[k], zb[k])
        p1 = za["p1"]
    # Another seed drives it differently.
    _, P8 = cr.simulate_continuum_robot(2, duration_s=20.0, seed=8)
    assert not np.allclose(P8[:, 0], p1, atol=1e-3)


def test_bad_arguments_raise_clear_errors(tmp_path):
    for bad in (0, 3, True, "2", 1.5):
        with pytest.raises(ValueError, match="n_segments must be 1 or 2"):
            cr.write_robot_npz(tmp_path / "x.npz", bad, duration_s=20.0)
    with pytest.raises(ValueError, match="duration_s must be positive"):
        cr.simulate_continuum_robot(2, duration_s=-1.0)
    with pytest.raises(ValueError, match="leaves no drive"):
        cr.simulate_continuum_robot(2, duration_s=3.0)
    with pytest.raises(ValueError, match="must start after the training share"):
        cr.simulate_continuum_robot(2, duration_s=30.0, tail_s=10.0)
    with pytest.raises(ValueError, match="rest interval"):
        cr.simulate_continuum_robot(2, duration_s=30.0, n_rest=6, rest_s=3.0)
    with pytest.raises(ValueError, match="must end in .npz"):
        cr.write_robot_npz(tmp_path / "x.h5", 2, duration_s=20.0)
    with pytest.raises(ValueError, match="unknown robot parameter"):
        cr.write_robot_npz(tmp_path / "x.npz", 2, duration_s=20.0, robot={"stiffness": 1.0})
    with pytest.raises(ValueError, match="k_bend needs one value per segment"):
        cr.ContinuumRobot.default(2, k_bend=(0.1, 0.1, 0.1))
    with pytest.raises(ValueError, match="zeta must be in"):
        cr.ContinuumRobot.default(1, zeta=1.5)
    with pytest.raises(TypeError):
        cr.simulate_continuum_robot(1, 20.0, not_a_parameter=1)
    with pytest.raises(ValueError, match=r"q must be a non-empty \[T, 4\]"):
        cr.render_continuum_robot(np.zeros((3, 2)), cr.ContinuumRobot.default(2))
    assert not any(tmp_path.iterdir())


def test_failed_write_leaves_nothing_behind(tmp_path, monkeypatch):
    path = tmp_path / "robot.npz"
    path.write_bytes(b"old")  # an earlier, complete artifact stays untouched

    def broken(fh, **arrays):
        fh.write(b"PK partial")
        raise OSError("disk full")

    import lagsplat.synth.continuum_robot.writer as writer

    monkeypatch.setattr(writer.np, "savez_compressed", broken)
    with pytest.raises(OSError, match="disk full"):
        cr.write_robot_npz(path, 1, duration_s=20.0)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["robot.npz"]
    assert path.read_bytes() == b"old"


def test_command_line(tmp_path, capsys):
    out = tmp_path / "x.npz"
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    cmd = [sys.executable, "-m", "lagsplat.synth.continuum_robot"]
    ok = subprocess.run([*cmd, "--segments", "2", "--out", str(out), "--duration-s", "30"], capture_output=True, text=True, env=env, check=False)
    assert ok.returncode == 0, ok.stderr
    assert ok.stdout.strip() == str(out)
    meta = json.loads((tmp_path / "x.npz.json").read_text())
    assert meta["n_frames"] == round(30 * cr.FPS)
    # Bad arguments: exit status 2 and one line on stderr (in-process, same entry point).
    for args in (["--segments", "3", "--out", str(tmp_path / "y.npz")], ["--segments", "2"],
                 ["--segments", "1", "--out", str(tmp_path / "y.npz"), "--duration-s", "-5"],
                 ["--segments", "1", "--out", str(tmp_path / "y.txt")]):
        capsys.readouterr()
        try:
            rc = cr.main(args)
        except SystemExit as exc:  # argparse's own checks
            rc = exc.code
        err = capsys.readouterr().err.strip().splitlines()
        assert rc == 2
        assert len(err) == 1 and "error" in err[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.npz", "x.npz.json"]
