"""Checks of the force transport on a known system (lagsplat.forces.checks; paper §3.4, Fig. 7)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lagsplat.forces.transport import ForceTransport
from lagsplat.forces.checks import (
    ForceCheckConfig,
    lever_profile,
    motion_masks,
    object_at_rest,
    plot_force_checks,
    run_force_checks,
)
from lagsplat.viewer.synthetic import synthetic_pendulum


def _rest(ae) -> np.ndarray:
    with torch.no_grad():
        return (ae.decode(torch.zeros(1, 1))[0].clamp(0, 1).permute(1, 2, 0).numpy() * 255 + 0.5).astype(np.uint8)


@pytest.fixture(scope="module")
def pendulum():
    ae, chart, model = synthetic_pendulum(size=64, seconds=4.0)
    with torch.no_grad():
        frames = ae.decode(torch.as_tensor(chart.q, dtype=torch.float32))
    images = (frames.clamp(0, 1).permute(0, 2, 3, 1).numpy() * 255 + 0.5).astype(np.uint8)
    return ae, chart, model, images


def test_motion_masks_separate_object_and_far_background():
    T, H, W = 20, 16, 24
    imgs = np.full((T, H, W, 3), 100, np.uint8)
    imgs[:, 6:9, 10:13] = (np.arange(T) * 7 % 255)[:, None, None, None]
    moving, static, std = motion_masks(imgs, sigma=1.0)
    assert moving[7, 11] and not moving[0, 0] and 9 <= moving.sum() <= 25  # std smoothed by 1 px
    assert static[0, 0] and not static[7, 11]
    assert not static[7, 14]  # 2 px from the moving block: within 3 sigma
    rest = imgs[0].copy()
    rest[6:9, 10:13] = 250  # 9 px: below the 10 px minimum, so the moving mask is used
    obj = object_at_rest(imgs, rest, moving)
    assert np.array_equal(obj, moving)
    rest[6:10, 10:14] = 250
    obj = object_at_rest(imgs, rest, moving)
    assert obj[7, 11] and not obj[0, 0] and obj.sum() <= 16
    with pytest.raises(ValueError, match="nothing moves"):
        motion_masks(np.zeros((3, 4, 4, 3), np.uint8), 1.0)


def test_checks_pass_on_a_decoder_with_static_background(pendulum):
    ae, chart, model, images = pendulum
    tr = ForceTransport.from_autoencoder(ae, chart)
    res = run_force_checks(model, tr, images, _rest(ae), ForceCheckConfig(grid=1))
    b = res["background"]
    assert res["n_object_points"] > 50 and res["n_background_points"] > 50
    assert b["passed"] and b["background_max_dq"] < 1e-3 * b["on_object_median_dq"]
    assert res["linearity"]["passed"] and res["linearity"]["f_lat_rel_err"] < 1e-12
    assert res["linearity"]["equilibrium_rel_err"] < 0.05  # first order in the force
    assert res["kernel"]["passed"] and res["kernel"]["rel"] < 1e-5


def test_background_check_fails_when_static_primitives_move(pendulum):
    """The same system with a Jacobian planted on background primitives must fail the check."""
    ae, chart, model, images = pendulum
    tr = ForceTransport.from_autoencoder(ae, chart)
    moving, static, _ = motion_masks(images, 1.5)
    ys, xs = np.nonzero(static)
    far = torch.tensor([[xs[0] + 0.5, ys[0] + 0.5]], dtype=torch.float32)
    near = ((tr.c - far) ** 2).sum(-1).sqrt() < 6.0
    assert near.any() and float(tr.J[near].abs().max()) == 0.0
    J = tr.J.clone()
    J[near] = tr.J.abs().max() * torch.tensor([1.0, 0.0])[:, None]
    bad = ForceTransport(tr.c, J, tr.alpha, tr.mu_q, tr.L_qq, tr.W_inv, tr.mean)
    res = run_force_checks(model, bad, images, _rest(ae), ForceCheckConfig(grid=1))
    assert not res["background"]["passed"] and res["background"]["ratio"] < 5


def test_lever_profile_is_linear_in_the_radius(pendulum, tmp_path):
    ae, chart, model, images = pendulum
    tr = ForceTransport.from_autoencoder(ae, chart)
    radii = np.linspace(6.0, 30.0, 7)
    prof = lever_profile(model, tr, pivot=(32.0, 8.0), direction=(0.0, 1.0), radii=radii, force=(1.0, 0.0), sigma=0.5)
    fl = prof["f_lat"][:, 0]
    # rigid rotation: J = (dy, -dx) px/rad, so a horizontal push at radius r gives
    # r, less what the brush takes from the background between the rod's
    # discrete primitives (2.4 px apart): growing, nearly proportional, <= r
    assert np.all(np.diff(fl) > 0) and np.all(fl <= radii + 1e-4) and np.all(fl > 0.6 * radii)
    assert np.corrcoef(radii, fl)[0, 1] > 0.98
    assert np.all(np.sign(prof["dq"][:, 0]) == np.sign(fl))
    res = run_force_checks(model, tr, images, _rest(ae))
    out = tmp_path / "forces.png"
    plot_force_checks(res, _rest(ae), out, title="synthetic", lever=prof)
    assert out.stat().st_size > 10_000 and not list(tmp_path.glob(".*.tmp"))
