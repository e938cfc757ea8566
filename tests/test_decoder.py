"""Tests of the conditioned-Gaussian decoder (lagsplat.models.decoder; paper §3.2,
Eqs. schur-mean, schur-cov, latent_opacity).

The closed forms of :class:`ConditionedGaussians` (Cholesky factor in (q, s)
order) are checked against textbook Gaussian conditioning of the full
covariance ``Sigma = decoder.covariance()``.
"""

from __future__ import annotations

import math

import pytest
import torch

from lagsplat.models import decoder as decoder_module
from lagsplat.models.decoder import ConditionedGaussians, inverse_softplus


def _random_decoder(K: int, d: int, seed: int, dtype=torch.float64) -> ConditionedGaussians:
    torch.manual_seed(seed)
    dec = ConditionedGaussians(K, d).to(dtype)
    with torch.no_grad():
        for p in dec.parameters():
            p.copy_(torch.randn_like(p))
        dec.L_raw.mul_(0.7)
    return dec


def _blocks(dec: ConditionedGaussians):
    """Full covariance, reordered to (s, q) and partitioned; plus the means."""
    d = dec.d
    S = dec.covariance()  # (q, s) order
    S_qq, S_qs = S[:, :d, :d], S[:, :d, d:]
    S_sq, S_ss = S[:, d:, :d], S[:, d:, d:]
    g = dec.geometry()
    return S, S_qq, S_qs, S_sq, S_ss, g.mu_s, g.mu_q


# ----------------------------------------------------------------------------- Schur conditioning
@pytest.mark.parametrize("d", [1, 2, 4])
def test_schur_conditioning_matches_brute_force(d: int) -> None:
    K, B = 7, 5
    dec = _random_decoder(K, d, seed=d)
    with torch.no_grad():
        S, S_qq, S_qs, S_sq, S_ss, mu_s, mu_q = _blocks(dec)
        # the factor is a valid Cholesky factor of an SPD matrix
        L = dec.cholesky()
        assert torch.equal(L, torch.tril(L))
        assert (torch.diagonal(L, dim1=-2, dim2=-1) >= 1e-4).all()
        assert (torch.linalg.eigvalsh(S) > 0).all()

        q = mu_q.mean(0) + torch.randn(B, d, dtype=torch.float64)
        means, gate, geom = dec.condition(q)
        assert means.shape == (B, K, 2) and gate.shape == (B, K)

        # (1) textbook formulas with an explicit inverse
        inv_qq = torch.linalg.inv(S_qq)
        J_ref = S_sq @ inv_qq  # [K,2,d]
        cov_ref = S_ss - S_sq @ inv_qq @ S_qs
        diff = q[:, None, :] - mu_q[None]  # [B,K,d]
        mean_ref = mu_s[None] + torch.einsum("kij,bkj->bki", J_ref, diff)
        torch.testing.assert_close(geom.J, J_ref, rtol=1e-9, atol=1e-10)
        torch.testing.assert_close(geom.cov, cov_ref, rtol=1e-9, atol=1e-10)
        torch.testing.assert_close(means, mean_ref, rtol=1e-9, atol=1e-10)

        # (2) via the precision matrix of the (s, q)-reordered covariance
        perm = list(range(d, d + 2)) + list(range(d))
        S_sqo = S[:, perm][:, :, perm]  # (s, q) order
        Lam = torch.linalg.inv(S_sqo)
        Lam_ss, Lam_sq = Lam[:, :2, :2], Lam[:, :2, 2:]
        cov_prec = torch.linalg.inv(Lam_ss)
        mean_prec = mu_s[None] - torch.einsum("kij,kjl,bkl->bki", cov_prec, Lam_sq, diff)
        torch.testing.assert_close(geom.cov, cov_prec, rtol=1e-8, atol=1e-10)
        torch.testing.assert_close(means, mean_prec, rtol=1e-8, atol=1e-10)

        # the conditional covariance is SPD and smaller than the marginal
        assert (torch.linalg.eigvalsh(geom.cov) > 0).all()
        assert (torch.linalg.eigvalsh(S_ss - geom.cov) > -1e-12).all()


@pytest.mark.parametrize("d", [1, 2, 4])
def test_gate_is_latent_gaussian_below_the_clamp(d: int) -> None:
    K = 9
    dec = _random_decoder(K, d, seed=10 + d)
    with torch.no_grad():
        _, S_qq, _, _, _, _, mu_q = _blocks(dec)
        gen = torch.Generator().manual_seed(d)
        # near primitive 0 (gate open for it), and far from everything (clamped)
        q = torch.cat([mu_q[:1] + 0.1 * torch.randn(3, d, generator=gen, dtype=torch.float64), mu_q[:1] + 1e3])
        _, gate, _ = dec.condition(q)
        diff = q[:, None, :] - mu_q[None]
        m2 = torch.einsum("bki,kij,bkj->bk", diff, torch.linalg.inv(S_qq), diff)
        below = m2 < 20.0
        assert below.sum() >= 3 and (~below).sum() >= K  # both regimes are exercised
        torch.testing.assert_close(gate[below], torch.exp(-0.5 * m2[below]), rtol=1e-9, atol=1e-12)
        torch.testing.assert_close(gate[~below], torch.full_like(gate[~below], math.exp(-10.0)), rtol=1e-12, atol=0)
        # the gate is exactly 1 at the latent mean
        _, gate0, _ = dec.condition(mu_q[3:4])
        assert gate0[0, 3].item() == pytest.approx(1.0, abs=1e-12)


@pytest.mark.parametrize("d", [1, 3])
def test_conditional_mean_is_affine_with_constant_jacobian(d: int) -> None:
    K = 5
    dec = _random_decoder(K, d, seed=20 + d)
    J = dec.geometry().J.detach()

    def mean_of(q):
        return dec.condition(q)[0]

    for q in (torch.zeros(1, d, dtype=torch.float64), 2.5 * torch.randn(1, d, dtype=torch.float64)):
        jac = torch.autograd.functional.jacobian(mean_of, q)  # [1,K,2,1,d]
        torch.testing.assert_close(jac[0, :, :, 0, :], J, rtol=1e-10, atol=1e-12)
    # affine: the midpoint maps to the midpoint
    with torch.no_grad():
        q1, q2 = torch.randn(2, 1, d, dtype=torch.float64)
        torch.testing.assert_close(mean_of(0.5 * (q1 + q2)), 0.5 * (mean_of(q1) + mean_of(q2)), rtol=1e-12, atol=1e-12)


def test_forward_passes_state_independent_covariance_and_gated_opacity(monkeypatch) -> None:
    K, d, H, W = 6, 2, 12, 20
    dec = _random_decoder(K, d, seed=3, dtype=torch.float32)
    calls = []

    def spy(means, covs, opacities, colors, height, width, background=None, backend="auto"):
        calls.append(dict(means=means, covs=covs, opac=opacities, colors=colors, hw=(height, width), bg=background))
        return torch.zeros(means.shape[0], 3, height, width)

    monkeypatch.setattr(decoder_module, "rasterize", spy)
    qs = [torch.zeros(1, d), torch.full((1, d), 3.0), torch.randn(2, d)]
    with torch.no_grad():
        for q in qs:
            dec(q, H, W)
        geom = dec.geometry()
    scale = torch.tensor([float(W), float(H)])
    cov_px = geom.cov * scale[None, :, None] * scale[None, None, :]
    for q, call in zip(qs, calls):
        assert call["hw"] == (H, W)
        torch.testing.assert_close(call["covs"], cov_px)  # identical for every q
        means, gate, _ = dec.condition(q)
        torch.testing.assert_close(call["means"], means.detach() * scale)
        torch.testing.assert_close(call["opac"], (geom.alpha[None] * gate).detach())
        torch.testing.assert_close(call["colors"], geom.colors)
    assert not torch.equal(calls[0]["opac"], calls[1]["opac"])  # the gate does depend on q


# ----------------------------------------------------------------------------- rendering
def test_forward_renders_images_in_unit_range() -> None:
    K, d, B, H, W = 40, 2, 3, 16, 24
    torch.manual_seed(0)
    dec = ConditionedGaussians(K, d, backend="cpu", background=(0.5, 0.25, 1.0))
    frame = torch.rand(3, H, W)
    dec.init_from_frame(frame, torch.randn(50, d), generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        dec.logit_alpha.fill_(4.0)  # nearly opaque: many alphas reach the 0.99 cap
        dec.logit_color.fill_(8.0)
    q = dec.mu_q[:B].detach().clone()
    img = dec(q, H, W)
    assert img.shape == (B, 3, H, W) and img.dtype == torch.float32
    assert img.min() >= 0.0 and img.max() <= 1.0
    assert img.std() > 0.01  # not a flat image
    for backend in ("torch", "dense"):
        torch.testing.assert_close(dec(q, H, W, backend=backend), img, atol=1e-5, rtol=0)
    # gradients reach every parameter
    dec(q, H, W, backend="torch").mean().backward()
    for name, p in dec.named_parameters():
        assert p.grad is not None and torch.isfinite(p.grad).all(), name
    # a far-away state closes every gate: only the background (to e^-10 opacity) remains
    with torch.no_grad():
        far = dec(q + 1e4, H, W)
    torch.testing.assert_close(far, dec.background.view(1, 3, 1, 1).expand_as(far), atol=1e-4, rtol=0)


def test_init_from_frame_places_colours_from_the_frame() -> None:
    K, d, H, W = 300, 2, 10, 12
    dec = ConditionedGaussians(K, d)
    gen = torch.Generator().manual_seed(2)
    frame = torch.rand(3, H, W, generator=gen)
    frame[:, :, 6:] = 1.0  # a vertical edge between columns 5 and 6
    frame[:, :, :6] = 0.8 * frame[:, :, :6]
    z = torch.randn(80, d, generator=gen) * torch.tensor([0.2, 2.0]) + torch.tensor([1.0, -3.0])
    dec.init_from_frame(frame, z, sigma_xy=0.05, sigma_q_floor=0.5, generator=torch.Generator().manual_seed(3))
    with torch.no_grad():
        g = dec.geometry()
    # positions are pixel centres, colours read at those pixels (clamped to [0.01, 0.99])
    pix = g.mu_s * torch.tensor([W, H]) - 0.5
    torch.testing.assert_close(pix, pix.round(), atol=1e-4, rtol=0)
    px, py = pix.round().long().unbind(-1)
    assert px.min() >= 0 and px.max() < W and py.min() >= 0 and py.max() < H
    torch.testing.assert_close(g.colors, frame[:, py, px].T.clamp(0.01, 0.99), atol=1e-5, rtol=0)
    # edges are favoured: column 5 (where the horizontal gradient is) is over-represented
    assert (px == 5).float().mean() > 2.0 / W
    # geometry: isotropic spatial extent sigma_xy, latent extent max(std z, floor), no coupling
    sig_q = max(float(z.std(0).max()), 0.5)
    torch.testing.assert_close(g.cov, torch.eye(2).expand(K, 2, 2) * 0.05**2, atol=1e-6, rtol=1e-4)
    torch.testing.assert_close(g.L_qq, torch.eye(d).expand(K, d, d) * sig_q, atol=1e-5, rtol=1e-4)
    assert g.J.abs().max() < 1e-6
    torch.testing.assert_close(g.alpha, torch.full((K,), 0.5))
    # latent means are spread like the encodings
    assert (g.mu_q.mean(0) - z.mean(0)).abs().max() < 0.5 * float(z.std(0).max())


def test_recycle_moves_exactly_the_dead_primitives() -> None:
    K, d, H, W = 30, 2, 8, 9
    dec = _random_decoder(K, d, seed=4, dtype=torch.float32)
    before = {k: v.detach().clone() for k, v in dec.named_parameters()}
    dead = torch.zeros(K, dtype=torch.bool)
    dead[[1, 7, 8, 22]] = True
    frame = torch.rand(3, H, W, generator=torch.Generator().manual_seed(5))
    rendered = frame.clone()
    rendered[:, 6, 2] += 0.5  # the only pixel with an error
    z_frame = torch.tensor([0.3, -1.2])
    z_std = torch.tensor([0.4, 0.9])
    dec.recycle(dead, frame, rendered, z_frame, z_std, sigma_xy=0.03, generator=torch.Generator().manual_seed(6))
    for k, v in dec.named_parameters():
        assert torch.equal(v.detach()[~dead], before[k][~dead]), k  # the living are untouched
        assert not torch.equal(v.detach()[dead], before[k][dead]), k  # the dead all moved
    with torch.no_grad():
        g = dec.geometry()
    n = int(dead.sum())
    torch.testing.assert_close(g.mu_q[dead], z_frame.expand(n, d))
    torch.testing.assert_close(g.mu_s[dead], torch.tensor([(2 + 0.5) / W, (6 + 0.5) / H]).expand(n, 2), atol=1e-5, rtol=0)
    torch.testing.assert_close(g.colors[dead], frame[:, 6, 2].clamp(0.01, 0.99).expand(n, 3), atol=1e-5, rtol=0)
    torch.testing.assert_close(g.alpha[dead], torch.full((n,), 1.0 / (1.0 + math.exp(3.0))))
    torch.testing.assert_close(g.L_qq[dead], torch.diag(z_std).expand(n, d, d), atol=1e-5, rtol=1e-4)
    torch.testing.assert_close(g.cov[dead], torch.eye(2).expand(n, 2, 2) * 0.03**2, atol=1e-6, rtol=1e-4)
    # nothing dead: a no-op
    snap = {k: v.detach().clone() for k, v in dec.named_parameters()}
    dec.recycle(torch.zeros(K, dtype=torch.bool), frame, rendered, z_frame, z_std)
    for k, v in dec.named_parameters():
        assert torch.equal(v.detach(), snap[k])


# ----------------------------------------------------------------------------- presence, pixel units
def test_presence_is_normalised_gated_opacity() -> None:
    K, d = 12, 3
    dec = _random_decoder(K, d, seed=5)
    q = torch.randn(4, d, dtype=torch.float64)
    with torch.no_grad():
        w = dec.presence(q)
        _, gate, g = dec.condition(q)
    assert w.shape == (4, K) and (w >= 0).all()
    torch.testing.assert_close(w.sum(-1), torch.ones(4, dtype=torch.float64), rtol=0, atol=1e-12)
    ref = g.alpha[None] * gate
    torch.testing.assert_close(w, ref / ref.sum(-1, keepdim=True), rtol=1e-12, atol=0)


def test_pixel_geometry_scales_rows_by_width_and_height() -> None:
    K, d, H, W = 5, 2, 30, 70
    dec = _random_decoder(K, d, seed=6)
    with torch.no_grad():
        g = dec.geometry()
        J_px, cov_px = dec.pixel_geometry(H, W)
    assert J_px.shape == (K, 2, d) and cov_px.shape == (K, 2, 2)
    torch.testing.assert_close(J_px[:, 0], W * g.J[:, 0], rtol=1e-12, atol=0)  # x row by the width
    torch.testing.assert_close(J_px[:, 1], H * g.J[:, 1], rtol=1e-12, atol=0)  # y row by the height
    torch.testing.assert_close(cov_px[:, 0, 0], W * W * g.cov[:, 0, 0], rtol=1e-12, atol=0)
    torch.testing.assert_close(cov_px[:, 1, 1], H * H * g.cov[:, 1, 1], rtol=1e-12, atol=0)
    torch.testing.assert_close(cov_px[:, 0, 1], W * H * g.cov[:, 0, 1], rtol=1e-12, atol=0)
    # J_px is the Jacobian of the pixel-space means that forward renders
    scale = torch.tensor([float(W), float(H)], dtype=torch.float64)
    jac = torch.autograd.functional.jacobian(lambda q: dec.condition(q)[0] * scale, torch.randn(1, d, dtype=torch.float64))
    torch.testing.assert_close(jac[0, :, :, 0, :], J_px, rtol=1e-10, atol=1e-12)


def test_condition_rejects_bad_shapes() -> None:
    dec = ConditionedGaussians(3, 2)
    with pytest.raises(ValueError):
        dec.condition(torch.zeros(4, 3))
    with pytest.raises(ValueError):
        dec.condition(torch.zeros(2))
    with pytest.raises(ValueError):
        ConditionedGaussians(0, 2)


def test_inverse_softplus() -> None:
    y = torch.tensor([1e-3, 0.05, 1.0, 7.0], dtype=torch.float64)
    torch.testing.assert_close(torch.nn.functional.softplus(inverse_softplus(y)), y, rtol=1e-12, atol=0)






def test_render_extra_channels_are_the_visible_brush_compositing_weights() -> None:
    """render(extra=J) composites J_i with the rasteriser's weights T_i a_i: the field the visible brush reads (lagsplat.forces.transport)."""
    from lagsplat.forces.transport import ForceTransport

    torch.manual_seed(1)
    H, W = 10, 14
    dec = ConditionedGaussians(40, 1)
    dec.init_from_frame(torch.rand(3, H, W), torch.randn(32, 1))
    with torch.no_grad():
        dec.L_raw[:, 1:3] = torch.randn(40, 2) * 0.3  # non-zero L_sq: J_i != 0
        dec.logit_alpha.normal_(1.0, 0.5)
    z = torch.tensor([[0.3]])
    J_px, cov_px = dec.pixel_geometry(H, W)
    img, field = dec.render(z, H, W, extra=J_px.reshape(40, -1))
    assert torch.allclose(img, dec(z, H, W))  # the colour channels are unchanged
    g = dec.geometry()
    means, gate, _ = dec.condition(z)
    tr = ForceTransport(means[0] * torch.tensor([W, H]), J_px, g.alpha, g.mu_q, g.L_qq, torch.eye(1), torch.zeros(1), cov_px)
    ys, xs = torch.meshgrid(torch.arange(H) + 0.5, torch.arange(W) + 0.5, indexing="ij")
    pts = torch.stack([xs.flatten(), ys.flatten()], 1)
    cw = tr.compositing_weights(means[0] * torch.tensor([W, H]), (g.alpha[None] * gate)[0], pts)  # [HW,K]
    expect = (cw @ J_px.reshape(40, -1)).T.reshape(2, H, W)
    assert float(expect.abs().max()) > 0.05  # not vacuous
    assert torch.allclose(field[0], expect, atol=1e-4)


def test_static_motion_penalty_reads_only_static_pixels_and_moves_matter_off_them() -> None:
    """Mean squared motion field over the static pixels; descent on it stops what is shown there from moving."""
    from lagsplat.train.losses import static_motion_penalty

    motion = torch.zeros(2, 2, 4, 5)
    motion[:, :, :, 3:] = 2.0  # moving matter on the two right columns
    static = torch.zeros(4, 5, dtype=torch.bool)
    static[:, :3] = True
    assert float(static_motion_penalty(motion, static)) == 0.0
    static[0, 4] = True  # one static pixel under moving matter: 2^2 + 2^2 over 13 pixels
    assert float(static_motion_penalty(motion, static)) == pytest.approx(8.0 / 13.0)
    assert float(static_motion_penalty(motion, torch.zeros(4, 5, dtype=torch.bool))) == 0.0

    torch.manual_seed(0)
    H, W = 8, 8
    dec = ConditionedGaussians(24, 1)
    dec.init_from_frame(torch.rand(3, H, W), torch.randn(16, 1))
    with torch.no_grad():
        dec.L_raw[:, 1:3] = torch.randn(24, 2) * 0.5
    static = torch.ones(H, W, dtype=torch.bool)
    z = torch.randn(4, 1)

    def penalty() -> torch.Tensor:
        return static_motion_penalty(dec.render_motion(z, H, W, torch.ones(1))[1], static)

    p0 = float(penalty())
    opt = torch.optim.Adam(dec.parameters(), lr=0.05)
    for _ in range(60):
        opt.zero_grad()
        penalty().backward()
        opt.step()
    assert p0 > 1.0 and float(penalty()) < 0.05 * p0
