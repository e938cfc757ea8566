"""The 3-D conditioned decoder: world-space Schur conditioning, EWA projection, depth order, checkpoints."""

import math

import numpy as np
import pytest
import torch

from lagsplat.models.autoencoder import AutoEncoder, load_stage1, save_stage1
from lagsplat.models.decoder3d import ConditionedGaussians3D
from lagsplat.models.deformation import build_decoder
from lagsplat.models.densify import split_overloaded
from lagsplat.models.encoder import CpAEEncoder
from lagsplat.render.camera import look_at, project_points
from lagsplat.render.rasterize_gsplat import gsplat_available
from lagsplat.train.losses import anisotropy_penalty

H = W = 32


def _cam(eye=(0.0, 0.0, -2.0)):
    return look_at(eye, (0.0, 0.0, 0.0), (0.0, -1.0, 0.0), W, H, 40.0)


def _decoder(K=2, d=1, cam=None):
    dec = ConditionedGaussians3D(K, d, cam or _cam(), depth_range=(1.5, 2.5), backend="dense")
    with torch.no_grad():
        dec.L_raw.copy_(dec._raw_diagonal(torch.ones(d), 0.05, K))
        dec.mu_q.zero_()
        dec.logit_alpha.fill_(4.0)
    return dec


def _centroid(img):
    w = img.detach().sum(0)
    ys, xs = torch.meshgrid(torch.arange(H) + 0.5, torch.arange(W) + 0.5, indexing="ij")
    return float((w * xs).sum() / w.sum()), float((w * ys).sum() / w.sum())


def test_conditioned_mean_is_affine_in_z_and_projects_where_the_camera_says():
    dec = _decoder(K=1)
    with torch.no_grad():
        dec.mu_raw.copy_(torch.tensor([[0.1, -0.05, 0.2]]))
        L = torch.diag(torch.tensor([1.0, 0.05, 0.05, 0.05]))
        L[1, 0] = 0.3  # Sigma_sq: the world x coordinate moves with z, J = L_sq L_qq^-1
        raw = L[dec.tril_i, dec.tril_j].clone()
        diag = dec.tril_i == dec.tril_j
        raw[diag] = torch.log(torch.expm1(raw[diag] - 1e-4))
        dec.L_raw.copy_(raw[None])
        dec.logit_color.fill_(5.0)
    g = dec.geometry()
    assert g.J.shape == (1, 3, 1) and g.cov.shape == (1, 3, 3)
    assert torch.allclose(g.J[0, :, 0], torch.tensor([0.3, 0.0, 0.0]), atol=1e-4)
    z = torch.tensor([[0.0], [0.5]])
    means, gate, _ = dec.condition(z)
    assert torch.allclose(means[1] - means[0], torch.tensor([[0.15, 0.0, 0.0]]), atol=1e-4)
    img = dec(z, H, W)
    uv, _ = project_points(means.detach(), dec.camera)
    for b in range(2):
        cx, cy = _centroid(img[b])
        assert abs(cx - float(uv[b, 0, 0])) < 0.3 and abs(cy - float(uv[b, 0, 1])) < 0.3
    assert _centroid(img[1])[0] > _centroid(img[0])[0] + 1.0  # world +x is image right for this camera


def test_the_nearer_primitive_covers_the_farther_one_whichever_its_index():
    dec = _decoder(K=2)
    with torch.no_grad():
        dec.logit_color.copy_(torch.tensor([[6.0, -6.0, -6.0], [-6.0, 6.0, -6.0]]))  # red, green
        dec.logit_alpha.fill_(8.0)
        for near in (0, 1):
            far = 1 - near
            dec.mu_raw.copy_(torch.zeros(2, 3))
            dec.mu_raw[near, 2] = -0.5  # the camera sits at z = -2 looking along +z
            dec.mu_raw[far, 2] = 0.5
            img = dec(torch.zeros(1, 1), H, W)[0]
            centre = img[:, H // 2, W // 2]
            assert centre[near] > 0.8 and centre[far] < 0.2


def test_a_primitive_behind_the_camera_is_not_drawn():
    dec = _decoder(K=1)
    with torch.no_grad():
        dec.mu_raw.copy_(torch.tensor([[0.0, 0.0, -3.0]]))
        dec.logit_color.fill_(5.0)
    assert float(dec(torch.zeros(1, 1), H, W).max()) == 0.0


def test_other_cameras_and_resolutions_see_the_same_world():
    dec = _decoder(K=1)
    with torch.no_grad():
        dec.mu_raw.copy_(torch.tensor([[0.2, 0.1, 0.0]]))
        dec.logit_color.fill_(5.0)
    side = look_at((2.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, -1.0, 0.0), W, H, 40.0)
    for cam, h, w in ((side, H, W), (dec.camera, 2 * H, 2 * W)):
        img = dec.render(torch.zeros(1, 1), h, w, camera=cam)[0][0]
        uv, _ = project_points(torch.tensor([0.2, 0.1, 0.0]), cam.resized(w, h))
        wsum = img.sum(0)
        ys, xs = torch.meshgrid(torch.arange(h) + 0.5, torch.arange(w) + 0.5, indexing="ij")
        c = torch.stack([(wsum * xs).sum(), (wsum * ys).sum()]) / wsum.sum()
        assert torch.allclose(c, uv, atol=0.4 * w / W)


def test_gradients_reach_every_parameter_through_projection_and_sorting():
    torch.manual_seed(0)
    dec = ConditionedGaussians3D(16, 2, _cam(), depth_range=(1.5, 2.5), backend="cpu")
    frame = torch.rand(3, H, W)
    dec.init_from_frame(frame, torch.randn(8, 2), sigma_xy=dec.spatial_sigma(0.05), generator=torch.Generator().manual_seed(0))
    # initial placement: on the pixels' rays, inside the depth range
    _, depth = project_points(dec.geometry().mu_s, dec.camera)
    assert float(depth.min()) >= 1.5 - 1e-5 and float(depth.max()) <= 2.5 + 1e-5
    loss = (dec(torch.randn(4, 2), H, W) - frame).abs().mean() + anisotropy_penalty(dec, H, W, 1.5)
    loss.backward()
    for name, p in dec.named_parameters():
        assert p.grad is not None and torch.isfinite(p.grad).all() and float(p.grad.abs().sum()) > 0, name


def test_splitting_keeps_world_positions_and_the_pair_straddles_the_parent():
    torch.manual_seed(1)
    dec = ConditionedGaussians3D(4, 1, _cam(), depth_range=(1.5, 2.5))
    dec.init_from_frame(torch.rand(3, H, W), torch.randn(8, 1), sigma_xy=0.02, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        dec.L_raw[0, -1] = 3.0  # primitive 0 stretched along world z
    mu0 = dec.geometry().mu_s[0].clone()
    dead = torch.tensor([False, False, False, True])
    used, split = split_overloaded(dec, dead, torch.ones(1), 0.02)
    assert bool(used[3]) and bool(split[0])
    mu = dec.geometry().mu_s
    assert torch.allclose(0.5 * (mu[0] + mu[3]), mu0, atol=1e-5)
    assert float((mu[0] - mu[3]).abs()[2]) > 0.5  # split along the long axis


def test_checkpoint_round_trip_keeps_the_camera(tmp_path):
    cam = _cam((0.3, -0.2, -2.0))
    dec = build_decoder("conditioned3d", 8, 1, backend="dense", camera=cam.to_dict(), depth_range=[1.0, 3.0])
    dec.init_from_frame(torch.rand(3, H, W), torch.randn(4, 1), sigma_xy=0.02, generator=torch.Generator().manual_seed(0))
    enc = CpAEEncoder(1, (2, 2, 2), 5)
    path = save_stage1(tmp_path / "stage1.pt", AutoEncoder(enc, dec, H, W), {"backend": "dense"}, {}, 1)
    ae = load_stage1(path)
    assert ae.decoder.kind == "conditioned3d" and ae.decoder.camera == cam
    z = torch.randn(2, 1)
    assert torch.equal(ae.decode(z), dec(z, H, W))


def test_bad_construction_is_refused():
    with pytest.raises(ValueError, match="camera"):
        build_decoder("conditioned3d", 4, 1)
    with pytest.raises(ValueError, match="depth_range"):
        ConditionedGaussians3D(4, 1, _cam(), depth_range=(2.0, 1.0))
    with pytest.raises(NotImplementedError):
        _decoder().pixel_geometry(H, W)
    assert math.isclose(_decoder().spatial_sigma(0.1), 0.1 * W * 2.0 / _cam().fx)


def test_new_primitives_go_on_the_rays_of_the_camera_that_saw_the_pixels():
    dec = _decoder(K=1)
    side = look_at((2.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, -1.0, 0.0), W, H, 40.0)
    idx = torch.tensor([0, 5 * W + 7, H * W - 1])
    X = dec.placement_raw(idx, H, W, torch.Generator().manual_seed(0), camera=side)
    uv, depth = project_points(X, side)
    expect = torch.stack([(idx % W).float() + 0.5, (idx // W).float() + 0.5], -1)
    assert torch.allclose(uv, expect, atol=1e-3)
    assert float(depth.min()) >= 1.5 - 1e-4 and float(depth.max()) <= 2.5 + 1e-4  # both cameras stand 2 m from the centre
    with pytest.raises(ValueError, match="no camera"):
        from lagsplat.models.decoder import ConditionedGaussians

        ConditionedGaussians(2, 1).placement_raw(idx, H, W, camera=side)


def test_render_depth_composites_the_depth_along_the_camera_axis():
    """Two primitives on the axis, at depths 1.8 and 2.3: each alone gives its own depth at the centre pixel; both
    together, a depth close to the front one's (it hides most of the one behind)."""
    dec = _decoder(K=2)
    with torch.no_grad():
        dec.mu_raw.copy_(torch.tensor([[0.0, 0.0, -0.2], [0.0, 0.0, 0.3]]))
    z, c = torch.zeros(1, 1), (slice(None), 0, H // 2, W // 2)

    def centre_depth(alpha_logits):
        with torch.no_grad():
            dec.logit_alpha.copy_(torch.tensor(alpha_logits))
        img, dep, alpha = dec.render_depth(z, H, W)
        assert img.shape == (1, 3, H, W) and dep.shape == alpha.shape == (1, 1, H, W)
        return float(dep[c] / alpha[c]), float(alpha[c])

    d_front, a_front = centre_depth([8.0, -30.0])
    d_back, _ = centre_depth([-30.0, 8.0])
    d_both, a_both = centre_depth([8.0, 8.0])
    assert d_front == pytest.approx(1.8, abs=1e-3) and d_back == pytest.approx(2.3, abs=1e-3)
    assert a_front > 0.8 and a_both > a_front
    w_back = (a_both - a_front) / a_both  # the share the back one gets through the front one
    assert d_both == pytest.approx((1 - w_back) * 1.8 + w_back * 2.3, abs=1e-3) and d_both < 2.0


@pytest.mark.skipif(not gsplat_available(), reason="needs the gsplat package and a CUDA device")
def test_gsplat_draws_the_3d_decoder_as_the_cpu_rasteriser_does():
    """On CUDA the projected, depth-sorted primitives go through gsplat's kernels: the image and the gradient of a
    loss with respect to the state agree with the CPU reference (up to the tails beyond 3 sigma that gsplat draws)."""
    torch.manual_seed(0)
    dec = ConditionedGaussians3D(64, 2, _cam(), depth_range=(1.5, 2.5), backend="dense")
    frame = torch.rand(3, H, W)
    dec.init_from_frame(frame, torch.randn(8, 2), sigma_xy=dec.spatial_sigma(0.05), generator=torch.Generator().manual_seed(0))
    z = torch.randn(3, 2)
    side = look_at((1.5, 0.0, -1.5), (0.0, 0.0, 0.0), (0.0, -1.0, 0.0), W, H, 40.0)
    target = torch.rand(3, 3, H, W)
    results = {}
    for dev, backend in (("cpu", "dense"), ("cuda", "gsplat")):
        dec.to(dev)
        zz = z.to(dev).requires_grad_(True)
        img = dec.render(zz, H, W, backend=backend)[0]
        img_side = dec.render(zz, H, W, backend=backend, camera=side)[0]
        loss = ((img - target.to(dev)) ** 2).mean() + ((img_side - target.to(dev)) ** 2).mean()
        (gz,) = torch.autograd.grad(loss, zz)
        assert img.device.type == dev
        results[dev] = (img.detach().cpu(), img_side.detach().cpu(), gz.cpu())
    for a, b in zip(results["cpu"][:2], results["cuda"][:2]):
        assert float((a - b).abs().mean()) < 0.01 and float((a - b).abs().max()) < 0.1
    g_cpu, g_cuda = results["cpu"][2].flatten(), results["cuda"][2].flatten()
    assert float(torch.nn.functional.cosine_similarity(g_cpu, g_cuda, dim=0)) > 0.95


def test_the_diagnosis_sees_3d_primitives_through_the_main_camera():
    """Pixel positions are the projected means, pixel Jacobians their derivative in q, and the compositing weights
    put the nearer of two overlapping primitives in front whichever its index."""
    from lagsplat.diagnose.screen import ScreenKinematics
    from lagsplat.forces.transport3d import ForceTransport3D

    dec = _decoder(K=2)
    with torch.no_grad():
        dec.mu_raw.copy_(torch.tensor([[0.0, 0.0, 0.5], [0.0, 0.0, -0.5]]))  # the second nearer the camera (at z = -2)
        L = torch.eye(4) * 0.05
        L[0, 0] = 1.0
        L[1, 0] = 0.3
        raw = L[dec.tril_i, dec.tril_j].clone()
        diag = dec.tril_i == dec.tril_j
        raw[diag] = torch.log(torch.expm1(raw[diag] - 1e-4))
        dec.L_raw.copy_(raw[None].expand(2, -1))

    class _Chart:
        W_inv, mean = np.eye(1), np.zeros(1)

    sk = ScreenKinematics(ForceTransport3D.from_autoencoder(type("AE", (), {"decoder": dec, "height": H, "width": W})(), _Chart()), dec.camera)
    q = torch.zeros(1, 1)
    uv, _ = project_points(sk.tr.means(q)[0], dec.camera)
    assert torch.allclose(sk.positions(q), uv)
    J = sk.pixel_jacobians(q)
    du = (sk.positions(q + 0.01) - sk.positions(q - 0.01)) / 0.02
    assert J.shape == (2, 2, 1) and torch.allclose(J[..., 0], du, atol=1e-3) and float(J[1, 0, 0]) > float(J[0, 0, 0]) > 0
    w = sk.weights(q, uv[1:2])  # at the nearer primitive's centre
    assert float(w[0, 1]) > 0.9 and float(w[0, 0]) < 0.1
