"""The deformation-field decoder and its comparison with the conditioned decoder (paper App. B).

The decoder renders, trains on a small synthetic clip through the unchanged
Stage-1 loop (loss falls), its forward-mode Jacobian matches autograd and
finite differences, ``stage1.pt`` round-trips the decoder family, the
roughness is ~0 on an affine velocity field and large on a random one, and
the stage runs end to end on the tiny toy at tiny budgets.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from lagsplat.baselines.deformation_compare import fast_frame, roughness
from lagsplat.models.autoencoder import load_stage1, save_stage1
from lagsplat.models.decoder import ConditionedGaussians
from lagsplat.models.deformation import DeformationGaussians, build_decoder
from lagsplat.synth.pendulum import make_pendulum_clip
from lagsplat.train.losses import anisotropy_penalty
from lagsplat.train.stage1 import Stage1Config, train_stage1

ROOT = Path(__file__).resolve().parents[1]


def _random_deformation(K: int = 40, d: int = 2, seed: int = 0, dtype=torch.float64) -> DeformationGaussians:
    torch.manual_seed(seed)
    dec = DeformationGaussians(K, d, backend="torch", hidden=(16, 12), n_freqs=2).to(dtype)
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        dec.mu_raw.copy_(torch.randn(K, 2, generator=g, dtype=dtype))
        dec.L_raw.copy_(0.3 * torch.randn(K, 3, generator=g, dtype=dtype) - 3.0)
        for p in (*dec.head_mu.parameters(), *dec.head_s.parameters()):
            p.copy_(0.3 * torch.randn(p.shape, generator=g, dtype=dtype))
    return dec


def test_jacobian_matches_autograd_and_finite_differences() -> None:
    dec = _random_deformation()
    H, W = 20, 30
    z = torch.tensor([[0.3, -0.7]], dtype=torch.float64)
    J = dec.pixel_jacobians(z, H, W)  # [K,2,d]
    scale = torch.tensor([W, H], dtype=torch.float64)
    pos = lambda zz: dec.condition(zz.reshape(1, -1))[0][0] * scale  # noqa: E731
    J_ad = torch.autograd.functional.jacobian(pos, z[0])  # [K,2,d]
    torch.testing.assert_close(J, J_ad, rtol=1e-9, atol=1e-9)
    h = 1e-6
    for j in range(2):
        e = torch.zeros(2, dtype=torch.float64)
        e[j] = h
        fd = (pos(z[0] + e) - pos(z[0] - e)) / (2 * h)
        torch.testing.assert_close(J[:, :, j], fd, rtol=1e-6, atol=1e-6)
    assert float(J.abs().max()) > 1e-2  # a field that moves, so the comparison means something
    # the Jacobian changes with the state (not affine)
    assert float((dec.pixel_jacobians(z + 1.0, H, W) - J).abs().max()) > 1e-3
    # the chart's Jacobian is J_z W_inv^T
    W_inv, mean = torch.tensor([[2.0, 0.5], [0.0, 1.0]], dtype=torch.float64), torch.tensor([0.1, -0.2], dtype=torch.float64)
    q = (z - mean) @ torch.linalg.inv(W_inv)
    mu, Jq = dec.state_kinematics(q, W_inv, mean, H, W)
    torch.testing.assert_close(mu[0], pos(z[0]))
    torch.testing.assert_close(Jq[0], torch.einsum("kid,ld->kil", J, W_inv))


def test_renders_moves_and_scales_with_the_state() -> None:
    dec = _random_deformation(dtype=torch.float32)
    z = torch.tensor([[0.0, 0.0], [1.0, -1.0]])
    img = dec(z, 16, 24)
    assert img.shape == (2, 3, 16, 24) and float(img.min()) >= 0 and float(img.max()) <= 1
    means, gate, g = dec.condition(z)
    assert torch.all(gate == 1.0)  # no latent gate
    assert g.cov.shape == (2, dec.K, 2, 2) and not torch.allclose(g.cov[0], g.cov[1])
    # extents are scaled, not sheared: the rendered covariance is a multiple of the canonical one
    ratio = g.cov[1, :, 0, 0] / g.cov[0, :, 0, 0]
    torch.testing.assert_close(g.cov[1], ratio[:, None, None] * g.cov[0])
    assert not torch.allclose(means[0], means[1])
    with pytest.raises(ValueError, match="no constant Jacobian"):
        dec.pixel_geometry(16, 24)
    with pytest.raises(ValueError, match="affinely"):
        dec.chart_kinematics(np.eye(2), np.zeros(2), 16, 24)
    with pytest.raises(ValueError, match=r"z must be \[B,2\]"):
        dec(torch.zeros(2, 3), 16, 24)


def test_motion_render_is_the_state_jacobian_composited() -> None:
    dec = _random_deformation(K=30, d=1, dtype=torch.float32)
    z = torch.tensor([[0.2], [-0.4]])
    img, motion = dec.render_motion(z, 12, 14, torch.tensor([1.0]))
    assert motion.shape == (2, 2, 12, 14)
    for b in range(2):
        J = dec.pixel_jacobians(z[b], 12, 14)  # [K,2,1]
        _, ref = dec.render(z[b : b + 1], 12, 14, extra=J.reshape(dec.K, 2))
        torch.testing.assert_close(motion[b : b + 1], ref, rtol=1e-5, atol=1e-5)


def test_no_latent_block_and_anisotropy_on_the_canonical_factor() -> None:
    dec = DeformationGaussians(8, 3)
    names = dict(dec.named_parameters())
    assert "mu_q" not in names and names["L_raw"].shape == (8, 3)
    assert [p.shape[0] for p in dec.primitive_parameters()] == [8] * 4
    with torch.no_grad():
        dec.L_raw[:, 0] = 3.0  # x std ~3, y std ~0.69: an elongated Gaussian
        dec.L_raw[:, 2] = 0.0
    assert float(anisotropy_penalty(dec, 10, 10, max_ratio=2.0)) > 0
    assert float(anisotropy_penalty(dec, 10, 10, max_ratio=10.0)) == 0
    with pytest.raises(ValueError, match="unknown decoder"):
        build_decoder("hexplane", 4, 1)


def test_trains_through_stage1_and_round_trips_the_checkpoint(tmp_path) -> None:
    clip = make_pendulum_clip(size=(24, 24), duration_s=4.0, seed=0)
    cfg = Stage1Config(decoder="deformation", n_gaussians=128, steps=120, recycle_warmup=40, recycle_every=40, threads=1,
                       deform_hidden=(32, 32), w_static=1e-2, plateau_patience=0)  # fmt: skip
    ae, hist = train_stage1(clip, cfg, d=1, seed=0, progress=False)
    assert isinstance(ae.decoder, DeformationGaussians) and ae.decoder.hidden == (32, 32)
    loss = np.asarray(hist["loss"])
    assert loss[-3:].mean() < 0.7 * loss[:3].mean(), loss  # the loss falls
    path = save_stage1(tmp_path / "stage1.pt", ae, {"decoder": "deformation"}, hist, 1)
    back = load_stage1(path)
    assert isinstance(back.decoder, DeformationGaussians) and back.decoder.hidden == (32, 32) and back.decoder.n_freqs == 4
    x = torch.from_numpy(clip.images[:4]).permute(0, 3, 1, 2).float() / 255
    with torch.no_grad():
        torch.testing.assert_close(back.decode(back.encode(x)), ae.decode(ae.encode(x)))
    # the conditioned decoder saves its family too, and a checkpoint without one is a conditioned decoder
    ck = torch.load(path, weights_only=False)
    assert ck["decoder_kind"] == "deformation"
    ae_c = type(ae)(ae.encoder, ConditionedGaussians(16, 1), 24, 24)
    ck_c = torch.load(save_stage1(tmp_path / "c.pt", ae_c, {}, {}, 1), weights_only=False)
    assert ck_c["decoder_kind"] == "conditioned"
    del ck_c["decoder_kind"], ck_c["decoder_options"]
    torch.save(ck_c, tmp_path / "old.pt")
    assert type(load_stage1(tmp_path / "old.pt").decoder) is ConditionedGaussians
    ck_c["decoder_kind"] = "nope"
    torch.save(ck_c, tmp_path / "bad.pt")
    with pytest.raises(ValueError, match="bad.pt.*unknown decoder"):
        load_stage1(tmp_path / "bad.pt")


def test_default_decoder_is_the_conditioned_one() -> None:
    assert Stage1Config().decoder == "conditioned"
    clip = make_pendulum_clip(size=(16, 16), duration_s=2.0, seed=0)
    ae, _ = train_stage1(clip, Stage1Config(n_gaussians=16, steps=3, threads=1), d=1, seed=0, progress=False)
    assert type(ae.decoder) is ConditionedGaussians and ae.decoder.latent_block == 1
    assert [n for n, _ in ae.decoder.named_parameters()] == ["mu_raw", "mu_q", "L_raw", "logit_alpha", "logit_color"]


def test_roughness_is_zero_on_an_affine_field_and_large_on_a_random_one() -> None:
    rng = np.random.default_rng(0)
    pos = rng.uniform(0, 100, size=(2000, 2))
    # an affine motion's speed is the norm of an affine function: smooth, neighbours ~ equal
    J = np.array([[0.3, -0.1], [0.05, 0.2]])
    speed = np.linalg.norm(pos @ J.T + np.array([2.0, -1.0]), axis=1)
    smooth = np.median(roughness(pos, speed, k=6))
    noisy = np.median(roughness(pos, rng.uniform(0, speed.max(), size=len(pos)), k=6))
    assert smooth < 0.02 * speed.mean(), (smooth, speed.mean())
    assert noisy > 20 * smooth and noisy > 0.1 * speed.mean()
    assert np.allclose(roughness(pos, np.full(len(pos), 3.0)), 0.0)  # a rigid translation: exactly 0
    with pytest.raises(ValueError, match="N >= 2"):
        roughness(pos[:1], speed[:1])


def test_fast_frame_picks_the_largest_velocity_inside_training_segments() -> None:
    t = np.arange(20) / 10.0
    q = np.sin(2 * np.pi * 0.5 * t)[:, None]  # fastest at t = 0, 1, 2 s
    frame, qd = fast_frame(q, t, np.arange(3, 20))
    assert frame == 10 and qd[0] < 0  # t = 1 s, descending (t = 0 is not inside the training frames)
    with pytest.raises(ValueError, match="consecutive"):
        fast_frame(q, t, np.array([0, 2, 4]))


@pytest.mark.slow
def test_stage_runs_end_to_end_on_the_tiny_toy(tmp_path) -> None:
    res = tmp_path / "results"
    tiny = ["stage1.retries=0", "stage1.deform_hidden=[16,16]", "stage2.epochs=2", "stage2.windows_per_epoch=50", "chart.gate=false",
            "chart.n_metric_samples=4"]  # fmt: skip
    run = lambda *a: subprocess.run([sys.executable, "-m", "lagsplat", *a, "system=toy_tiny", f"results_dir={res}", "threads=1", "progress=false", *tiny],  # noqa: E731
                                    cwd=ROOT, capture_output=True, text=True, timeout=900)  # fmt: skip
    for stage in ("ingest", "stage1", "chart", "stage2"):
        r = run(stage)
        assert r.returncode == 0, r.stderr[-2000:]
    r = run("deformation")
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    sysdir = res / "toy_tiny"
    assert (sysdir / "variants" / "deformation" / "stage1.pt").exists() and (sysdir / "figures" / "deformation.png").exists()
    assert (sysdir / "variants" / "deformation" / "config" / "stage1.yaml").exists()  # the run's own config untouched
    assert "decoder: conditioned" in (sysdir / "config" / "stage1.yaml").read_text()
    rec = json.loads((res / "tables" / "deformation.json").read_text())
    rows = {r["decoder"]: r for r in rec["rows"]}
    assert set(rows) == {"conditioned", "deformation"}
    for r in rows.values():
        assert 0 < r["l1"] < 1 and 0 <= r["ssim_term"] <= 2 and r["params_total"] > r["params_decoder"] > 0
        assert r["n_visible"] > 0 and np.isfinite(r["roughness_median_px_s"])
        assert 0 < r["n_object"] and 0 < r["n_static"] and r["n_object"] + r["n_static"] <= r["n_visible"]  # disjoint parts of the image
    assert rows["deformation"]["params_decoder"] != rows["conditioned"]["params_decoder"]
    # the synthetic pendulum has a rigid-body truth: both decoders pushed through the same forces
    # (at these budgets a decoder may not move the pushed material enough to calibrate kappa: the reason is recorded;
    # the force read-outs themselves are checked on a known pendulum below)
    for kind in ("conditioned", "deformation"):
        f = rec["forces"][kind]
        assert ("kappa" in f and len(f["rows"]) == 12 and f["rows"][0]["calibration"]) or "not reached" in f["error"], f
    csv = (res / "tables" / "deformation.csv").read_text().splitlines()
    assert len(csv) == 3 and "roughness_median_px_s" in csv[0]
    assert "Deformation field" in (res / "tables" / "deformation.tex").read_text()
    # a second run reuses the variant (no retraining)
    r2 = run("deformation")
    assert r2.returncode == 0 and "reusing" in r2.stdout


class _SinPendulum:
    """A stand-in Lagrangian: potential ``1 - cos q`` (force unit ``I w0^2``), so the loaded equilibrium is ``sin q = f``."""

    q_rest = torch.zeros(1)

    def loaded_equilibrium(self, f_ext, q0=None):
        return torch.asin(f_ext.double().clamp(-0.999, 0.999))

    def eval(self):
        return self


def test_state_dependent_jacobians_reach_the_rigid_body_equilibrium() -> None:
    from lagsplat.baselines.deformation_forces import StateTransport, loaded_state, true_angle
    from lagsplat.forces.transport import Selection

    class Rod(StateTransport):  # a point at rho px from the pivot: J(q) = rho (cos q, -sin q), exactly
        def __init__(self, rho):
            self.rho = rho

        def jacobians(self, q):
            th = float(q[0, 0])
            return torch.tensor([[[self.rho * math.cos(th)], [-self.rho * math.sin(th)]]], dtype=torch.float32)

    rho, sel = 20.0, Selection(torch.ones(1, 1))
    for F in ((0.12, 0.0), (-0.10, -0.03), (0.08, 0.08)):
        q = loaded_state(_SinPendulum(), Rod(rho), sel, torch.tensor([F]), 1.0 / rho, torch.zeros(1, 1), tol=1e-9)
        assert abs(float(q[0, 0]) - true_angle(F, 1.0)) < 1e-5, F


def test_force_truth_of_constant_jacobians_is_the_eq9_floor() -> None:
    from types import SimpleNamespace

    from lagsplat.baselines.deformation_forces import force_truth, true_angle
    from lagsplat.io.clip import Clip
    from lagsplat.models.autoencoder import AutoEncoder
    from lagsplat.models.encoder import CpAEEncoder
    from lagsplat.synth.pendulum import PIVOT_Y, ROD_LENGTH
    from lagsplat.viewer.synthetic import decoder_from_primitives

    H = W = 64
    L_px, piv = ROD_LENGTH * H, np.array([W / 2, PIVOT_Y * H])
    r = np.linspace(-0.2, 1.05, 60)
    pos = piv[None] + np.stack([np.zeros_like(r), r * L_px], 1)
    J = np.stack([r * L_px, np.zeros_like(r)], 1)  # rest Jacobians of the rigid rotation, px per rad
    dec = decoder_from_primitives(pos, J, np.full((60, 3), 0.6), np.full(60, 0.95), np.full(60, 1.2), H, W)
    ae = AutoEncoder(CpAEEncoder(1), dec, H, W)
    T = 60
    theta = 0.15 * np.sin(np.linspace(0, 6 * np.pi, T))
    chart = SimpleNamespace(W_inv=np.eye(1), mean=np.zeros(1), q=theta[:, None])  # q is the angle itself
    clip = Clip(images=np.zeros((T, H, W, 3), np.uint8), t=np.arange(T) / 30.0, split=np.zeros(T, np.int8), meta={"theta": theta.tolist()})
    res = force_truth(ae, chart, _SinPendulum(), clip, sigma=1.5)
    rows = res["rows"]
    assert abs(rows[0]["chart_mag_err_pct"]) < 1e-4 and abs(rows[0]["point_mag_err_pct"]) < 1e-4  # calibrated on it
    # a horizontal push on the rod: the constant-J equilibrium sin q = kappa r L Fx misses the true one by under 2 %
    row = rows[1]
    assert row["force"] == [0.12, 0.0] and row["scored"] and abs(row["chart_mag_err_pct"]) < 2.0 and abs(row["chart_dir_err_deg"]) < 1.0
    assert abs(row["true_angle_deg"] - math.degrees(true_angle((0.12, 0.0), 1.0))) < 1e-9
    # a vertical pull changes the stiffness, which a constant Jacobian cannot carry (paper Eq. 9's own floor)
    assert abs(rows[-1]["chart_mag_err_pct"]) > 5.0
    # the counter-arm 0.12 rod above the pivot moved under a pixel in the clip: reported, not scored
    assert not rows[10]["scored"] and rows[10]["seen_px"] < 1.0
    assert res["summary"]["chart"]["n_scored"] == sum(r["scored"] for r in rows)
