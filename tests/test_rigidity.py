"""The infinitesimal-rigidity prior on the decoder's Jacobians (stage1.w_rigid; lagsplat.train.losses.rigidity_penalty)."""

from __future__ import annotations

import math

import pytest
import torch

from lagsplat.models.decoder import ConditionedGaussians
from lagsplat.synth.pendulum import make_pendulum_clip
from lagsplat.train.losses import rigidity_penalty
from lagsplat.train.stage1 import Stage1Config, train_stage1
from lagsplat.models.autoencoder import frames_to_tensor

H = W = 32


def _decoder(xy_px: torch.Tensor, J_px: torch.Tensor, colors: torch.Tensor) -> ConditionedGaussians:
    """A d = 1 decoder with primitives at ``xy_px [K,2]`` (at z = 0), Jacobians ``J_px [K,2]`` px per unit z, RGB ``colors``."""
    K = len(xy_px)
    dec = ConditionedGaussians(K, 1)
    scale = torch.tensor([float(W), float(H)])
    with torch.no_grad():
        dec.mu_raw.copy_(torch.logit(((xy_px / scale) + 0.1) / 1.2))
        dec.logit_alpha.fill_(4.0)
        dec.logit_color.copy_(torch.logit(colors.clamp(0.01, 0.99)))
        dec.L_raw.zero_()
        l_qq = dec.cholesky()[0, 0, 0].item()  # softplus(0) + floor: the latent block the Jacobian divides by
        dec.L_raw[:, 1] = J_px[:, 0] / W * l_qq  # (1, 0): L_sq, x
        dec.L_raw[:, 3] = J_px[:, 1] / H * l_qq  # (2, 0): L_sq, y
    g = dec.geometry()
    assert torch.allclose(g.J[:, :, 0] * scale, J_px, atol=1e-4)
    return dec


def _grid(n: int = 8, step: float = 1.0, x0: float = 12.0, y0: float = 12.0) -> torch.Tensor:
    ii, jj = torch.meshgrid(torch.arange(n), torch.arange(n), indexing="ij")
    return torch.stack([x0 + step * jj.reshape(-1), y0 + step * ii.reshape(-1)], 1).float()


def _penalty(dec: ConditionedGaussians) -> torch.Tensor:
    return rigidity_penalty(dec, torch.zeros(1), torch.ones(1), H, W)


def _value(dec: ConditionedGaussians) -> float:
    return float(_penalty(dec).detach())


def test_rigid_motion_costs_nothing_and_stretching_does() -> None:
    xy = _grid()
    grey = torch.full((len(xy), 3), 0.5)
    pivot = torch.tensor([3.0, 5.0])
    rel = xy - pivot
    rotation = 0.7 * torch.stack([-rel[:, 1], rel[:, 0]], 1) + torch.tensor([2.0, -1.0])  # a rotation and a translation
    stretch = 0.7 * torch.stack([rel[:, 0], torch.zeros(len(xy))], 1)  # the same size of motion, not rigid
    p_rot, p_str = _value(_decoder(xy, rotation, grey)), _value(_decoder(xy, stretch, grey))
    assert p_rot < 1e-6 * p_str, (p_rot, p_str)
    # a pair 1 px apart stretching at 0.7 px per unit z: e = 0.7 / 1.5 (length_px), for the horizontal pairs
    assert 0.05 < p_str < 0.7**2, p_str


def test_only_the_jacobians_receive_gradient() -> None:
    xy = _grid(4)
    J = torch.randn(len(xy), 2, generator=torch.Generator().manual_seed(0))
    dec = _decoder(xy, J, torch.full((len(xy), 3), 0.5))
    _penalty(dec).backward()
    assert dec.L_raw.grad is not None and float(dec.L_raw.grad[:, [1, 3]].abs().sum()) > 0
    for p in (dec.mu_raw, dec.logit_alpha, dec.logit_color):
        assert p.grad is None or float(p.grad.abs().sum()) == 0.0


def test_different_colours_are_not_bound_together() -> None:
    # a dark moving block beside a light static one: two bodies, not one stretching body
    xy = _grid(8)
    left = xy[:, 0] < 16.0
    J = torch.zeros(len(xy), 2)
    J[left, 0] = 1.0
    dark, light = torch.tensor([0.2, 0.2, 0.25]), torch.tensor([0.9, 0.9, 0.85])
    two_colours = torch.where(left[:, None], dark, light)
    p_two = _value(_decoder(xy, J, two_colours))
    p_one = _value(_decoder(xy, J, dark.expand(len(xy), 3)))
    assert p_one > 0.01 and p_two < 1e-3 * p_one, (p_one, p_two)
    assert math.isfinite(p_two)


@pytest.mark.slow
def test_stage1_with_the_prior_moves_its_primitives_more_rigidly() -> None:
    clip = make_pendulum_clip(size=(32, 32), duration_s=6.0, seed=0)
    X = frames_to_tensor(clip.images[clip.train_idx])
    base = dict(n_gaussians=256, steps=250, recycle_warmup=100, recycle_every=50, threads=1)
    out = []
    for w in (0.0, 1e-2):
        ae, _ = train_stage1(clip, Stage1Config(**base, w_rigid=w), d=1, seed=0, progress=False)
        with torch.no_grad():
            z = ae.encode(X)
            mse = float((ae.decode(z) - X).pow(2).mean())
        out.append((float(rigidity_penalty(ae.decoder, z.mean(0), z.std(0), 32, 32).detach()), mse))
    (r0, mse0), (r1, mse1) = out
    assert r1 < 0.25 * r0, (r0, r1)  # px^2 of stretching per latent std between neighbours
    assert mse1 < 3.0 * mse0, (mse0, mse1)  # the reconstruction is not traded away
