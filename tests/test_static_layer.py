"""The decoder's static layer (ConditionedGaussians ``backdrop``; stage1.static_layer).

A learned image behind the primitives draws what never moves; it carries no
``q``, so nothing of it enters ``J``, the motion field or a generalized force
(paper Eq. 9), and it round-trips through ``stage1.pt``.
"""

from __future__ import annotations

import pytest
import torch

from lagsplat.models.autoencoder import AutoEncoder, load_stage1, save_stage1
from lagsplat.models.decoder import ConditionedGaussians
from lagsplat.models.deformation import build_decoder
from lagsplat.models.densify import placement_probability
from lagsplat.models.encoder import CpAEEncoder
from lagsplat.render.rasterize import rasterize_dense


def _decoder(H: int = 10, W: int = 12, K: int = 8) -> ConditionedGaussians:
    torch.manual_seed(0)
    dec = ConditionedGaussians(K, 1, backend="dense", backdrop=(H, W))
    dec.init_from_frame(torch.rand(3, H, W), torch.randn(16, 1), sigma_xy=0.06)
    with torch.no_grad():
        dec.L_raw[:, 1:3] = torch.randn(K, 2) * 0.3  # primitives that move with q
        dec.logit_alpha.normal_(0.5, 0.5)
    dec.set_backdrop(torch.rand(3, H, W) * 0.8 + 0.1)
    return dec


def test_the_image_is_the_primitives_over_the_backdrop() -> None:
    dec = _decoder()
    H, W = 10, 12
    z = torch.tensor([[0.2], [-0.7]])
    means, gate, g = dec.condition(z)
    uv, covs, op, col = dec.screen(means, gate, g, g.colors, H, W)
    over_black = rasterize_dense(uv, covs, op, col, H, W)
    cover = rasterize_dense(uv, covs, op, torch.ones(dec.K, 1), H, W)  # 1 - prod(1 - a_i) per pixel
    expect = (over_black + (1 - cover) * dec.backdrop_image(H, W)[None]).clamp(0, 1)
    assert float(cover.detach().min()) < 0.5 < float(cover.detach().max())  # some pixels show the backdrop, some the primitives
    assert torch.allclose(dec(z, H, W), expect, atol=1e-5)


def test_transparent_primitives_show_the_backdrop_and_it_learns() -> None:
    dec = _decoder()
    with torch.no_grad():
        dec.logit_alpha.fill_(-30.0)
    img = dec(torch.zeros(1, 1), 10, 12)
    assert torch.allclose(img[0], dec.backdrop_image(10, 12), atol=1e-5)
    img.sum().backward()
    assert dec.backdrop_raw.grad is not None and float(dec.backdrop_raw.grad.abs().min()) > 0
    assert dec.backdrop_image(20, 24).shape == (3, 20, 24)  # another resolution: resampled


def test_no_motion_and_no_force_on_the_backdrop() -> None:
    """The extra channels (the motion field a force is pulled back through) keep a zero background."""
    dec = _decoder()
    J_px, _ = dec.pixel_geometry(10, 12)
    z = torch.tensor([[0.1]])
    _, field = dec.render(z, 10, 12, extra=J_px.reshape(dec.K, -1))
    plain = ConditionedGaussians(dec.K, 1, backend="dense")
    plain.load_state_dict({k: v for k, v in dec.state_dict().items() if k != "backdrop_raw"})
    _, field0 = plain.render(z, 10, 12, extra=J_px.reshape(dec.K, -1))
    assert float(field.detach().abs().max()) > 0.01 and torch.allclose(field, field0, atol=1e-6)
    assert all(p is not dec.backdrop_raw for p in dec.primitive_parameters())


def test_stage1_checkpoint_keeps_the_static_layer(tmp_path) -> None:
    dec = _decoder()
    ae = AutoEncoder(CpAEEncoder(1, (2, 2, 2), 5), dec, 10, 12)
    path = save_stage1(tmp_path / "stage1.pt", ae, {"backend": "dense"}, {}, 1)
    back = load_stage1(path)
    assert back.decoder.backdrop_raw is not None
    z = torch.tensor([[0.3]])
    assert torch.allclose(back.decode(z), ae.decode(z), atol=1e-6)


def test_the_static_layer_is_refused_for_the_3d_decoder_and_bad_sizes() -> None:
    with pytest.raises(ValueError, match="static layer"):
        build_decoder("conditioned3d", 8, 1, camera={}, backdrop=(4, 4))
    with pytest.raises(ValueError, match="backdrop"):
        ConditionedGaussians(8, 1, backdrop=(0, 4))
    with pytest.raises(ValueError, match="no static layer"):
        ConditionedGaussians(8, 1).set_backdrop(torch.zeros(3, 4, 4))
    dec = build_decoder("deformation", 8, 1, backdrop=(4, 5))
    assert dec.options()["backdrop"] == [4, 5]


def test_placement_goes_where_the_frame_departs_from_the_backdrop() -> None:
    back = torch.full((3, 16, 16), 0.5)
    back[:, ::2] = 0.1  # strong stripes: edges everywhere, all of them static
    frame = back.clone()
    frame[:, 4:8, 4:8] = 0.9  # the object
    p = placement_probability(frame, backdrop=back).reshape(16, 16)
    assert float(p[4:8, 4:8].sum()) > 0.5 * float(p.sum())  # 16 of 256 pixels
    p0 = placement_probability(frame).reshape(16, 16)  # the edge draw spreads over the stripes
    assert float(p0[4:8, 4:8].sum()) < 0.2 * float(p0.sum())


@pytest.mark.slow
def test_stage1_with_a_static_layer_draws_the_motion() -> None:
    """Stage 1 with the static layer keeps the moving object in the primitives: decoded frames differ where it moves."""
    from lagsplat.models.autoencoder import frames_to_tensor
    from lagsplat.synth.pendulum import make_pendulum_clip
    from lagsplat.train.stage1 import Stage1Config, train_stage1

    clip = make_pendulum_clip(size=(32, 32), duration_s=6.0, seed=0)
    cfg = Stage1Config(n_gaussians=256, steps=300, recycle_warmup=100, recycle_every=50, threads=1, sigma_xy=0.05, static_layer=True)
    ae, _ = train_stage1(clip, cfg, d=1, seed=0, progress=False)
    X = frames_to_tensor(clip.images[clip.train_idx])
    with torch.no_grad():
        z = ae.encode(X)
        rec = ae.decode(z)
    assert ae.decoder.backdrop_raw is not None and float(z.std()) > 0.1  # the encodings did not collapse
    change_true = (X - X.mean(0)).pow(2).mean()
    change_rec = (rec - rec.mean(0)).pow(2).mean()
    assert float(change_rec) > 0.3 * float(change_true)  # the decoder draws the motion, not only the layer
