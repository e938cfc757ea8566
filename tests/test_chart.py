"""Whitening, loss metric, visibility metric and the fold diagnostic of the chart."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lagsplat.chart import chart_continuity, fit_whitening, loss_metric, visibility_metric
from lagsplat.models.decoder import ConditionedGaussians
from lagsplat.models.encoder import CpAEEncoder
from lagsplat.models.autoencoder import AutoEncoder, frames_to_tensor


def test_whitening_gives_identity_covariance_and_inverts():
    rng = np.random.default_rng(0)
    z = rng.normal(size=(500, 3)) @ np.array([[3.0, 0.5, 0.0], [0.0, 1.0, 0.2], [0.0, 0.0, 0.1]]) + 5.0
    mean, W, W_inv = fit_whitening(z)
    q = (z - mean) @ W
    np.testing.assert_allclose(np.cov(q, rowvar=False), np.eye(3), atol=1e-4)
    np.testing.assert_allclose(q @ W_inv + mean, z, atol=1e-8)
    # columns ordered by decreasing raw variance: the first direction is the dominant one
    assert np.abs(W_inv[0]).argmax() == 0


def test_whitening_needs_more_samples_than_dimensions():
    with pytest.raises(ValueError):
        fit_whitening(np.zeros((2, 3)))


def test_loss_metric_trace_and_ridge():
    G = np.diag([100.0, 1.0, 0.0])
    A = loss_metric(G, rho=0.01)
    assert np.trace(A) == pytest.approx(3.0)
    ev = np.linalg.eigvalsh(A)
    assert ev.max() / ev.min() <= 1 / 0.01 + 1 + 1e-9  # weighting ratio capped by 1/rho
    np.testing.assert_allclose(loss_metric(np.eye(2) * 7.0), np.eye(2))  # G ∝ I gives the Euclidean loss


def test_continuity_separates_smooth_and_torn_trajectories():
    t = np.arange(300) / 30.0
    q = np.sin(2 * np.pi * 0.8 * t)[:, None]
    split = np.zeros(300, np.int8)
    smooth = chart_continuity(q, split, np.eye(1))
    torn = q.copy()
    torn[100:104] -= 1.0  # an isolated excursion, as a folded encoder produces
    assert smooth < 1.0
    assert chart_continuity(torn, split, np.eye(1)) > 5.0


def test_visibility_metric_matches_the_reverse_mode_jacobian():
    """Forward-mode JVPs through the tile renderer equal the exact Jacobian of the
    dense reference (finite differences are no reference here: they straddle the
    rule's hard cut-offs at 1/255 and 3 sigma)."""
    torch.manual_seed(0)
    dec = ConditionedGaussians(64, 2)
    frame = torch.rand(3, 16, 16)
    dec.init_from_frame(frame, torch.randn(50, 2))
    with torch.no_grad():  # give the primitives a latent-dependent motion
        dec.L_raw[:, 3:5] = torch.randn(64, 2) * 0.2
    ae = AutoEncoder(CpAEEncoder(2), dec, 16, 16)
    q = np.array([[0.1, -0.2], [0.3, 0.4]])
    G, sv = visibility_metric(ae, np.zeros(2), np.eye(2), q)
    G_ref = np.zeros((2, 2))
    for qi in torch.tensor(q, dtype=torch.float32):
        J = torch.autograd.functional.jacobian(lambda x: dec(x[None], 16, 16, backend="dense").flatten(), qi).double()
        G_ref += (J.T @ J).numpy() / J.shape[0] / len(q)
    np.testing.assert_allclose(G, G_ref, rtol=1e-4, atol=1e-9)
    assert G[0, 0] > 0 and G[1, 1] > 0
    assert sv.shape == (2, 2)


class _SaturatingEncoder(torch.nn.Module):
    """A stand-in encoder: the blob's horizontal centroid (px from the centre, / 4 px per unit), saturating at +-0.8.

    An amortised encoder reads the extreme images short in the same way (the
    blind suite's 32 px clips: up to 0.3 short at the turning points).
    """

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        w = x.mean(1).sum(1)  # [B, W] brightness per column
        cols = torch.arange(x.shape[-1], dtype=x.dtype)
        c = (w * cols).sum(1) / w.sum(1) - (x.shape[-1] - 1) / 2
        return (c / 4.0).clamp(-0.8, 0.8)[:, None]


def _blob_autoencoder(size: int = 24) -> AutoEncoder:
    from lagsplat.viewer.synthetic import decoder_from_primitives

    # a bright blob on the black background: moves 4 px per unit z
    dec = decoder_from_primitives([[size / 2 - 0.5, size / 2 - 0.5]], [[4.0, 0.0]], [[0.9, 0.9, 0.9]], [0.95], [2.5], size, size)
    return AutoEncoder(_SaturatingEncoder(), dec, size, size)


def _blob_clip(ae: AutoEncoder, z: np.ndarray):
    from lagsplat.io.clip import Clip

    with torch.no_grad():
        img = ae.decode(torch.as_tensor(z, dtype=torch.float32)).clamp(0, 1)
    frames = (img.permute(0, 2, 3, 1).numpy() * 255).round().astype(np.uint8)
    split = np.zeros(len(z), np.int8)
    split[int(0.7 * len(z)) :] = 1
    return Clip(images=frames, t=np.arange(len(z)) / 30.0, split=split)


def test_refine_latents_undoes_a_saturating_encoder():
    """Paper §3.2: the chart is read through the decoder; the refined latents are where it draws each frame."""
    from lagsplat.chart.refine import refine_latents

    ae = _blob_autoencoder()
    z_true = 1.2 * np.sin(2 * np.pi * np.arange(90) / 30.0)[:, None]
    clip = _blob_clip(ae, z_true)
    z_enc = ae.encode_frames(clip.images).numpy().astype(np.float64)
    assert np.abs(z_enc - z_true).max() > 0.35  # the encoder reads the turning points 0.4 short
    z_ref, mse = refine_latents(ae, clip.images, z_enc, iters=8)
    assert np.abs(z_ref - z_true).max() < 0.03
    with torch.no_grad():
        x = frames_to_tensor(clip.images)
        mse_enc = ((ae.decode(torch.as_tensor(z_enc, dtype=torch.float32)) - x) ** 2).mean(dim=(1, 2, 3)).numpy()
    assert np.all(mse <= mse_enc + 1e-12)  # a step is taken only where it lowers the error
    assert mse.mean() < 0.1 * mse_enc.mean()


def test_build_chart_refines_only_when_asked():
    from lagsplat.chart import build_chart

    ae = _blob_autoencoder()
    z_true = 1.2 * np.sin(2 * np.pi * np.arange(90) / 30.0)
    clip = _blob_clip(ae, z_true[:, None])

    def affine_misfit(q: np.ndarray) -> float:  # the chart is z up to the whitening's affine map
        A = np.stack([z_true, np.ones_like(z_true)], 1)
        coef, *_ = np.linalg.lstsq(A, q[:, 0], rcond=None)
        return float(np.abs(A @ coef - q[:, 0]).max() / np.ptp(q[:, 0]))

    plain = build_chart(ae, clip, n_metric_samples=8)
    refined = build_chart(ae, clip, n_metric_samples=8, refine_iters=8)
    assert plain.meta["refine_iters"] == 0 and plain.meta["refine_rms_shift"] == 0.0
    assert affine_misfit(plain.q) > 0.08
    assert affine_misfit(refined.q) < 0.02
    assert refined.meta["refine_rms_shift"] > 0.1
    assert refined.ae_floor_train < 0.2 * plain.ae_floor_train


def test_refine_latents_rejects_mismatched_input():
    from lagsplat.chart.refine import refine_latents

    ae = _blob_autoencoder()
    frames = np.zeros((4, 24, 24, 3), np.uint8)
    with pytest.raises(ValueError, match="4 frames but 3 latents"):
        refine_latents(ae, frames, np.zeros((3, 1)))
    with pytest.raises(ValueError, match="iters"):
        refine_latents(ae, frames, np.zeros((4, 1)), iters=-1)
