"""Motion-aware placement and the split of an overloaded Gaussian (lagsplat.models.densify, paper App. C)."""

from __future__ import annotations

import torch

from lagsplat.models.decoder import ConditionedGaussians
from lagsplat.models.densify import overload, placement_probability, split_overloaded


def _decoder(K: int = 6, d: int = 1) -> ConditionedGaussians:
    dec = ConditionedGaussians(K, d)
    dec.init_from_frame(torch.rand(3, 16, 16, generator=torch.Generator().manual_seed(0)), torch.randn(40, d), generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        dec.logit_alpha[:] = 2.0
    return dec


def test_placement_follows_the_motion():
    frame = torch.full((3, 20, 20), 0.5)
    std = torch.zeros(20, 20)
    std[5:8, 5:8] = 0.3
    plain, moving = placement_probability(frame), placement_probability(frame, std, 1.0)
    assert torch.allclose(plain, torch.full_like(plain, 0.2))  # a flat frame: uniform
    p = (moving / moving.sum()).reshape(20, 20)
    assert abs(float(p[5:8, 5:8].sum()) - 9 * 1.2 / (400 * 0.2 + 9)) < 1e-6  # 6x the share of a still pixel each
    assert torch.equal(placement_probability(frame, std, 0.0), plain)


def test_a_gaussian_stretched_along_q_splits_into_two_halves_of_the_range():
    dec = _decoder()
    with torch.no_grad():  # primitive 2: latent extent 3 (the whole range) and moving 0.1 image widths per unit q
        L = torch.zeros(3, 3)
        L[0, 0], L[1, 0], L[2, 0] = 3.0, 0.3, 0.0
        L[1, 1], L[2, 2] = 0.03, 0.03
        dec.L_raw[2] = 0.0
        for k, (i, j) in enumerate(zip(dec.tril_i.tolist(), dec.tril_j.tolist())):
            v = L[i, j]
            dec.L_raw[2, k] = torch.log(torch.expm1(v - 1e-4)) if i == j else v
        dec.mu_q[2] = 0.0
    z_std = torch.ones(1)
    score, _ = overload(dec, z_std, 0.03)
    assert int(score.argmax()) == 2
    J_before = dec.geometry().J[2].clone()
    mu_s_before = dec.geometry().mu_s[2].clone()
    dead = torch.zeros(6, dtype=torch.bool)
    dead[4] = True
    used, split = split_overloaded(dec, dead, z_std, 0.03)
    assert used.tolist() == dead.tolist() and split.nonzero().flatten().tolist() == [2]
    g = dec.geometry()
    # the two halves sit at -+ 1.5 on q (half a standard deviation of 3), on the parent's line of motion
    assert torch.allclose(torch.sort(torch.stack([g.mu_q[2, 0], g.mu_q[4, 0]])).values, torch.tensor([-1.5, 1.5]), atol=0.02)
    for k in (2, 4):
        assert torch.allclose(g.J[k], J_before, atol=0.005)  # about the same motion per unit q
        assert torch.allclose(g.mu_s[k], mu_s_before + J_before[:, 0] * g.mu_q[k, 0], atol=0.005)
    # the latent extent is halved (variance quartered along the principal axis)
    assert torch.allclose(torch.diagonal(g.L_qq[2]).abs(), torch.tensor([1.5]), atol=0.02)
    assert torch.equal(dec.logit_color[4], dec.logit_color[2])


def test_no_alive_primitive_no_split():
    dec = _decoder(K=3)
    dead = torch.ones(3, dtype=torch.bool)
    used, split = split_overloaded(dec, dead, torch.ones(1), 0.03)
    assert not used.any() and not split.any()
