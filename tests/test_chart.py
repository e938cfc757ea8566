"""Whitening, loss metric, visibility metric and the fold diagnostic of the chart."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lagsplat.chart import chart_continuity, fit_whitening, loss_metric, visibility_metric
from lagsplat.models.decoder import ConditionedGaussians
from lagsplat.models.encoder import CpAEEncoder
from lagsplat.train.stage1 import AutoEncoder


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
