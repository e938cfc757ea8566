"""Tests of the Stage-1 loss terms (lagsplat.train.losses) that have an outside reference."""

from __future__ import annotations

import warnings

import pytest
import torch
from pytorch_msssim import ssim as reference_ssim

from lagsplat.train.losses import ssim


@pytest.mark.parametrize("shape,win", [((3, 3, 20, 17), 7), ((2, 3, 5, 64), 7), ((4, 3, 64, 64), 7), ((1, 3, 9, 9), 3), ((2, 1, 32, 32), 11)])
def test_ssim_equals_pytorch_msssim_with_its_gradient(shape, win) -> None:
    """Value and gradient equal ``pytorch_msssim.ssim`` (data range 1), including an axis shorter than the window."""
    g = torch.Generator().manual_seed(sum(shape) + win)
    pred = torch.rand(*shape, generator=g, requires_grad=True)
    target = (pred.detach() + 0.2 * torch.randn(*shape, generator=g)).clamp(0, 1)
    ours = ssim(pred, target, win_size=win)
    (g_ours,) = torch.autograd.grad(ours, pred)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the reference warns when it skips the short axis
        ref = reference_ssim(pred, target, data_range=1.0, win_size=win)
    (g_ref,) = torch.autograd.grad(ref, pred)
    assert 0.1 < float(ref) < 0.99
    assert abs(float(ours) - float(ref)) < 1e-6
    assert float((g_ours - g_ref).abs().max()) <= 1e-5 * float(g_ref.abs().max())


def test_ssim_is_one_on_identical_images_and_rejects_bad_input() -> None:
    x = torch.rand(2, 3, 16, 16, generator=torch.Generator().manual_seed(0))
    assert float(ssim(x, x)) == pytest.approx(1.0, abs=1e-6)
    with pytest.raises(ValueError, match="one shape"):
        ssim(x, x[:, :, :8])
    with pytest.raises(ValueError, match="odd"):
        ssim(x, x, win_size=6)


def test_temporal_curvature_penalty_sees_a_tear_not_a_smooth_chart():
    import numpy as np

    from lagsplat.train.losses import temporal_curvature_penalty

    t = torch.arange(120, dtype=torch.float32)
    z = torch.sin(2 * np.pi * t / 40.0)[:, None]  # 40 frames per period
    c = torch.arange(1, 119)
    smooth = temporal_curvature_penalty(torch.stack([z[c - 1], z[c], z[c + 1]]), z)
    torn = z.clone()
    torn[60:] += 2.0  # neighbouring frames 59 and 60 sent far apart
    tear = temporal_curvature_penalty(torch.stack([torn[c - 1], torn[c], torn[c + 1]]), torn)
    assert smooth < 1e-2 and tear > 10 * smooth
    # scale-free: the same chart, stretched, costs the same
    assert torch.isclose(temporal_curvature_penalty(torch.stack([3 * z[c - 1], 3 * z[c], 3 * z[c + 1]]), 3 * z), smooth)
