"""The anchored Stage-1 start (lagsplat.train.anchor; stage1.anchor_steps).

The object's path read from the frames follows a small square moving over a
textured scene, the encoder learns to follow it, and the anchored primitives
sit on the object at the encodings of their frames.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lagsplat.models.decoder import ConditionedGaussians, latent_gate
from lagsplat.models.encoder import CpAEEncoder
from lagsplat.train.anchor import anchor_primitives, object_path, prefit_encoder


def _frames(n: int = 48, H: int = 24, W: int = 32, seed: int = 0) -> tuple[torch.Tensor, np.ndarray]:
    """A 4x4 green square swinging left-right (2 periods) before a fixed random texture: ``([n,3,H,W], x [n])``."""
    rng = np.random.default_rng(seed)
    scene = rng.uniform(0.2, 0.6, (3, H, W)).astype(np.float32)
    x = 14 + 9 * np.sin(2 * np.pi * 2 * np.arange(n) / n)
    X = np.repeat(scene[None], n, 0)
    for i, xi in enumerate(x):
        c = int(round(xi))
        X[i, :, 10:14, c : c + 4] = np.array([0.1, 0.9, 0.1], np.float32)[:, None, None]
    return torch.from_numpy(X), x


def test_the_path_follows_the_object_over_a_textured_scene() -> None:
    X, x = _frames()
    s = object_path(X).numpy()
    assert abs(np.corrcoef(s, x)[0, 1]) > 0.99
    assert abs(s.mean()) < 1e-5 and abs(s.std(ddof=1) - 1.0) < 1e-4


def test_the_path_needs_two_frames() -> None:
    with pytest.raises(ValueError, match="at least 2 frames"):
        object_path(torch.rand(1, 3, 8, 8))


def test_the_prefit_encoder_follows_the_path() -> None:
    torch.manual_seed(0)
    X, x = _frames()
    s = object_path(X)
    enc = CpAEEncoder(1, (2, 2, 2), 5)
    with torch.no_grad():
        before = float(np.corrcoef(enc(X)[:, 0].numpy(), x)[0, 1])
    loss = prefit_encoder(enc, X, s, steps=300, lr=3e-3, batch=16, rng=np.random.default_rng(0))
    with torch.no_grad():
        after = float(np.corrcoef(enc(X)[:, 0].numpy(), x)[0, 1])
    assert loss < 0.2 and abs(after) > 0.9 and abs(after) > abs(before)
    assert np.isnan(prefit_encoder(enc, X, s, steps=0, lr=1e-3, batch=16, rng=np.random.default_rng(0)))


def test_anchored_primitives_sit_on_the_object_at_their_frames_encodings() -> None:
    torch.manual_seed(0)
    X, x = _frames()
    N = X.shape[0]
    z = torch.from_numpy(((x - x.mean()) / x.std()).astype(np.float32))[:, None]
    dec = ConditionedGaussians(64, 1, backend="dense")
    gen = torch.Generator().manual_seed(0)
    dec.init_from_frame(X[0], z, sigma_xy=0.05, generator=gen)
    n = anchor_primitives(dec, X, z, share=0.25, sigma_xy=0.05, generator=gen, n_frames=4)
    assert n == 16
    # the scene's primitives are open over the whole range of the encodings: the scene draws the same at every state
    assert torch.allclose(dec.mu_q[16:], z.mean(0).expand(48, -1))
    gate = latent_gate(z, dec.geometry().mu_q, dec.geometry().L_qq).detach()  # [N,K]
    assert float(gate[:, 16:].min()) > 0.8 and float(gate[:, :16].min()) < 0.01
    frames = np.unique(np.linspace(0, N - 1, 4).round().astype(int))
    for k, j in enumerate(frames):
        rows = torch.arange(4 * k, 4 * (k + 1))
        assert torch.allclose(dec.mu_q[rows], z[j].expand(4, -1))
        colour = torch.sigmoid(dec.logit_color[rows].detach())  # drawn where the frame departs: on the object
        assert float(colour[:, 1].min()) > 0.85 and float(colour[:, 0].max()) < 0.15  # the green object's colour
    assert anchor_primitives(dec, X, z, share=0.0, sigma_xy=0.05, generator=gen) == 0


def test_stage1_anchored_start_draws_the_object_from_the_first_step() -> None:
    """With stage1.anchor_steps, the decoder draws the moving object where it is before any joint training step;
    the default start from the first frame does not (its latent means are drawn at random)."""
    from lagsplat.models.autoencoder import frames_to_tensor
    from lagsplat.synth.pendulum import make_pendulum_clip
    from lagsplat.train.stage1 import Stage1Config, train_stage1

    clip = make_pendulum_clip(size=(32, 32), duration_s=4.0, seed=0)
    X = frames_to_tensor(clip.images[clip.train_idx])
    change_true = float((X - X.mean(0)).pow(2).mean())
    drawn = {}
    for steps in (0, 300):
        cfg = Stage1Config(n_gaussians=256, steps=1, threads=1, sigma_xy=0.05, anchor_steps=steps)
        ae, _ = train_stage1(clip, cfg, d=1, seed=0, progress=False)
        with torch.no_grad():
            rec = ae.decode(ae.encode(X))
        drawn[steps] = float((rec - rec.mean(0)).pow(2).mean()) / change_true
    # measured: 0.21 of the frames' change drawn after one step with the anchor, 1e-6 without
    assert drawn[300] > 0.1 and drawn[0] < 1e-3
