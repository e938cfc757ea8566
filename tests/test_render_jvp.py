"""The compiled forward-mode pass of the rasteriser and the visibility metric it serves (paper Eq. 6).

The tangent must be the exact directional derivative of the image: the same as forward-mode AD through the
pure-torch tile rasteriser (the reference implementation of the compositing rule).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lagsplat.chart import visibility_metric
from lagsplat.models.autoencoder import AutoEncoder
from lagsplat.models.decoder import ConditionedGaussians
from lagsplat.models.decoder_jvp import render_jvp, supports_render_jvp
from lagsplat.models.encoder import CpAEEncoder
from lagsplat.render.rasterize import rasterize_tiles
from lagsplat.render.rasterize_cpu import rasterize_cpu_jvp

pytest.importorskip("numba")


def test_the_compiled_tangent_is_forward_mode_ad_through_the_torch_rasteriser() -> None:
    g = torch.Generator().manual_seed(0)
    B, K, H, W = 2, 40, 21, 37  # tiles cut by the image's edges
    means = torch.rand(B, K, 2, generator=g) * torch.tensor([W, H])
    A = torch.randn(K, 2, 2, generator=g) * 2.0
    covs = A @ A.transpose(1, 2) + 0.5 * torch.eye(2)
    opac = torch.rand(B, K, generator=g) * 0.9 + 0.05
    colors = torch.rand(K, 3, generator=g)
    bg = torch.tensor([0.2, 0.5, 0.9])
    d_means, d_opac = torch.randn(B, K, 2, generator=g), torch.randn(B, K, generator=g) * 0.1

    img, tan = rasterize_cpu_jvp(means, covs, opac, colors, d_means, d_opac, H, W, background=bg)
    ref, ref_tan = torch.func.jvp(lambda m, o: rasterize_tiles(m, covs, o, colors, H, W, background=bg), (means, opac), (d_means, d_opac))
    assert torch.allclose(img, ref, atol=2e-5)
    assert float(ref_tan.abs().max()) > 0.05  # the tangent is not trivially zero
    assert torch.allclose(tan, ref_tan, atol=2e-4 * float(ref_tan.abs().max()))


@pytest.mark.parametrize("backdrop", [False, True])
def test_the_visibility_metric_is_the_same_by_the_compiled_pass_and_by_torch(backdrop: bool, monkeypatch) -> None:
    torch.manual_seed(1)
    H, W, K, d = 20, 24, 32, 2
    dec = ConditionedGaussians(K, d, backdrop=(H, W) if backdrop else None)
    dec.init_from_frame(torch.rand(3, H, W), torch.randn(16, d), sigma_xy=0.08)
    with torch.no_grad():
        dec.L_raw[:, 1:5] = torch.randn(K, 4) * 0.4  # primitives that move with q
        dec.logit_alpha.normal_(0.5, 0.5)
    if backdrop:
        dec.set_backdrop(torch.rand(3, H, W) * 0.8 + 0.1)
    ae = AutoEncoder(CpAEEncoder(d), dec, H, W)
    assert supports_render_jvp(dec)
    q = np.random.default_rng(0).normal(size=(12, d))
    mean, W_inv = np.array([0.1, -0.2]), np.array([[1.0, 0.2], [0.0, 0.8]])
    G_fast, s_fast = visibility_metric(ae, mean, W_inv, q)
    monkeypatch.setattr("lagsplat.models.decoder_jvp.supports_render_jvp", lambda dec: False)
    G_ref, s_ref = visibility_metric(ae, mean, W_inv, q)
    assert float(np.abs(G_ref).max()) > 0
    np.testing.assert_allclose(G_fast, G_ref, rtol=1e-4, atol=1e-9)
    np.testing.assert_allclose(s_fast, s_ref, rtol=1e-4, atol=1e-7)


def test_render_jvp_refuses_another_decoder_and_mismatched_shapes() -> None:
    dec = ConditionedGaussians(8, 1)
    with pytest.raises(ValueError, match="one shape"):
        render_jvp(dec, torch.zeros(2, 1), torch.zeros(3, 1), 8, 8)

    class Other(ConditionedGaussians):
        pass

    assert not supports_render_jvp(Other(8, 1))
    with pytest.raises(ValueError, match="2-D conditioned decoder"):
        render_jvp(Other(8, 1), torch.zeros(1, 1), torch.zeros(1, 1), 8, 8)
