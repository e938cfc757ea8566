"""Force transport (paper §3.4, Eq. 9; App. A.1): pull-back, brush, selection, kappa, edits."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from lagsplat.dynamics.integrators import rollout
from lagsplat.forces.transport import EditedDynamics, ForceTransport, calibrate_kappa
from lagsplat.models.decoder import ConditionedGaussians
from lagsplat.models.lagrangian import Lagrangian


def _seesaw(n: int = 21, length: float = 20.0, pivot=(32.0, 32.0), brush: str = "paper") -> ForceTransport:
    """A bar through a pivot, rotating by the angle q (d = 1), plus static background primitives.

    Point-like primitives 2 px apart, with the paper's brush (exact symmetry
    about the pivot); the visible brush is tested on a rendered scene below.

    Primitive i sits at signed radius r_i on the bar; for small rotations
    mu_i(q) = pivot + r_i (1, 0) + r_i q (0, 1), so J_i = (0, r_i) (pixels per radian).
    """
    r = torch.linspace(-length, length, n)
    c_bar = torch.stack([pivot[0] + r, torch.full_like(r, pivot[1])], 1)
    J_bar = torch.stack([torch.zeros_like(r), r], 1)[:, :, None]
    bg = torch.tensor([[4.0, 4.0], [60.0, 4.0], [4.0, 60.0], [60.0, 60.0]])
    c = torch.cat([c_bar, bg])
    J = torch.cat([J_bar, torch.zeros(4, 2, 1)])
    K = len(c)
    return ForceTransport(
        c, J, torch.full((K,), 0.9), torch.zeros(K, 1), torch.full((K, 1, 1), 100.0), torch.eye(1), torch.zeros(1), brush=brush
    )


def _model(d: int = 1) -> Lagrangian:
    torch.manual_seed(0)
    m = Lagrangian(d, hidden=(16, 16))
    m.init_energy_scales(2 * math.pi * 1.0, 0.05)
    return m.eval()


def _push(tr, m, x, f, sigma=1.5):
    q0 = m.q_rest.detach()[None]
    sel = tr.select(q0, torch.tensor([x], dtype=torch.float32), sigma)
    return float((m.loaded_equilibrium(tr.pullback(sel, torch.tensor([f], dtype=torch.float32)), q0=q0) - q0)[0, 0])


def test_response_grows_with_the_lever_arm_and_flips_across_the_pivot():
    tr, m = _seesaw(), _model()
    arms = [4.0, 8.0, 16.0]
    right = [_push(tr, m, [32 + a, 32], [0, 1.0]) for a in arms]
    left = [_push(tr, m, [32 - a, 32], [0, 1.0]) for a in arms]
    assert right[0] > 0 and np.all(np.diff(right) > 0)
    np.testing.assert_allclose(left, [-x for x in right], rtol=1e-2)  # V is nonlinear: equal up to its asymmetry
    q0 = torch.zeros(1, 1)
    sel_l, sel_r = (tr.select(q0, torch.tensor([[32.0 + s, 32.0]]), 1.5) for s in (-8, 8))
    f = torch.tensor([[0.0, 1.0]])
    np.testing.assert_allclose(tr.pullback(sel_l, f).numpy(), -tr.pullback(sel_r, f).numpy(), rtol=1e-5)
    np.testing.assert_allclose(np.array(right) / right[0], np.array(arms) / arms[0], rtol=0.05)  # torque = r f


def test_background_force_moves_nothing_and_linearity_holds():
    tr, m = _seesaw(), _model()
    on = abs(_push(tr, m, [48, 32], [0, 1.0]))
    off = abs(_push(tr, m, [60, 60], [0, 1.0]))
    assert off < on / 50
    one, two, neg = (_push(tr, m, [48, 32], [0, s]) for s in (0.5, 1.0, -0.5))
    # the generalized force is exactly linear in f; the equilibrium nearly so for small loads
    q0 = m.q_rest.detach()[None]
    sel = tr.select(q0, torch.tensor([[48.0, 32.0]]), 1.5)
    f1, f2 = torch.tensor([[0.0, 1.0]]), torch.tensor([[0.3, -2.0]])
    np.testing.assert_allclose(tr.pullback([sel, sel], [f1, f2]).numpy(), tr.pullback(sel, f1 + f2).numpy(), rtol=1e-6)
    assert two == pytest.approx(2 * one, rel=0.02) and neg == pytest.approx(-one, rel=0.02)


def test_force_orthogonal_to_every_jacobian_transports_to_zero():
    tr = _seesaw()
    q0 = torch.zeros(1, 1)
    sel = tr.select(q0, torch.tensor([[40.0, 32.0]]), 6.0)
    assert float(tr.pullback(sel, torch.tensor([[5.0, 0.0]])).abs().max()) < 1e-6  # along the bar
    assert float(tr.pullback(sel, torch.tensor([[0.0, 5.0]])).abs().max()) > 1.0


def test_selection_is_frozen_and_follows_the_material():
    tr = _seesaw()
    q0 = torch.zeros(1, 1)
    sel = tr.select(q0, torch.tensor([[44.0, 32.0]]), 1.0)
    assert float(sel.weights.sum()) == pytest.approx(1.0)
    p = tr.application_point(torch.tensor([[0.1]]), sel)
    np.testing.assert_allclose(p.numpy(), [[44.0, 32.0 + 12.0 * 0.1]], atol=1e-4)
    empty = tr.select(q0, torch.tensor([[500.0, 500.0]]), 1.0)
    assert float(empty.weights.abs().sum()) == 0.0
    with pytest.raises(ValueError, match="sigma"):
        tr.select(q0, torch.tensor([[1.0, 1.0]]), 0.0)


def test_transport_from_a_decoder_matches_its_rendered_means():
    torch.manual_seed(0)
    dec = ConditionedGaussians(30, 2)
    dec.init_from_frame(torch.rand(3, 12, 20), torch.randn(40, 2))
    with torch.no_grad():
        dec.L_raw[:, 3:5] = torch.randn(30, 2) * 0.3

    class AE:
        decoder, height, width = dec, 12, 20

    class Ch:
        W_inv = np.array([[1.2, 0.1], [-0.4, 0.9]])
        mean = np.array([0.3, -0.1])

    tr = ForceTransport.from_autoencoder(AE, Ch)
    q = torch.randn(4, 2)
    z = q @ torch.as_tensor(Ch.W_inv, dtype=torch.float32) + torch.as_tensor(Ch.mean, dtype=torch.float32)
    mu, gate, g = dec.condition(z)
    np.testing.assert_allclose(tr.means(q).detach().numpy(), (mu * torch.tensor([20.0, 12.0])).detach().numpy(), atol=1e-4)
    np.testing.assert_allclose(tr.opacity(q).detach().numpy(), (g.alpha[None] * gate).detach().numpy(), atol=1e-6)


def test_kappa_calibration_recovers_a_known_scale():
    tr, m = _seesaw(), _model()
    q0 = m.q_rest.detach()[None]
    sel = tr.select(q0, torch.tensor([[44.0, 32.0]]), 1.5)
    f = torch.tensor([[0.0, 2.0]])
    kappa_true = 7.5
    q_eq = m.loaded_equilibrium(kappa_true * tr.pullback(sel, f), q0=q0)
    disp = float((tr.application_point(q_eq, sel) - tr.application_point(q0, sel)).norm())
    assert calibrate_kappa(m, tr, sel, f, disp) == pytest.approx(kappa_true, rel=1e-4)
    with pytest.raises(ValueError, match="positive"):
        calibrate_kappa(m, tr, sel, f, 0.0)


def test_edited_dynamics_scale_frequency_and_damping_as_physics_says():
    m = _model()
    q0, v0 = m.q_rest.detach()[None] + 0.05, torch.zeros(1, 1)
    base = m.modal_analysis()
    stiff = EditedDynamics(m, stiffness=4.0)
    heavy = EditedDynamics(m, inertia=4.0)
    same = EditedDynamics(m)
    a = m.acceleration(q0, torch.full((1, 1), 0.3)).detach()
    np.testing.assert_allclose(same.acceleration(q0, torch.full((1, 1), 0.3)).numpy(), a.numpy(), rtol=1e-5)
    from lagsplat.timeseries import spectral_peak_frequency

    def freq(dyn):
        q, _ = rollout(dyn, q0, v0, 1 / 60, 60 * 12, fast=False)
        return spectral_peak_frequency(q[0, :, 0].numpy() - float(m.q_rest), 1 / 60)

    f0 = freq(m)
    assert f0 == pytest.approx(base["f_damped_hz"][0], rel=0.02)
    assert freq(stiff) == pytest.approx(2 * f0, rel=0.03)
    assert freq(heavy) == pytest.approx(f0 / 2, rel=0.03)
    with pytest.raises(ValueError, match="damping"):
        EditedDynamics(m, damping=0.0)


def test_visible_brush_selects_a_thin_rod_in_front_of_an_opaque_background():
    """A 4 px rod (J = (r, 0) at radius r) over a dense opaque static background.

    The paper's brush averages the rod with the background primitives behind it
    and under-reports the rod's motion; the visible brush takes what the click
    touches in the render (compositing weights), so it recovers J = r.
    """
    r = torch.arange(0.0, 30.0, 1.0).repeat(3)
    x_rod = torch.tensor([31.0, 32.0, 33.0]).repeat_interleave(30)
    c_rod = torch.stack([x_rod, 4.0 + r], 1)
    J_rod = torch.stack([r, torch.zeros_like(r)], 1)[:, :, None]
    gy, gx = torch.meshgrid(torch.arange(0.5, 64, 2.0), torch.arange(0.5, 64, 2.0), indexing="ij")
    c_bg = torch.stack([gx.reshape(-1), gy.reshape(-1)], 1)
    c = torch.cat([c_rod, c_bg])  # rod first: it composites in front
    J = torch.cat([J_rod, torch.zeros(len(c_bg), 2, 1)])
    K = len(c)
    cov = torch.cat([torch.eye(2).expand(len(r), 2, 2) * 0.7**2, torch.eye(2).expand(len(c_bg), 2, 2) * 1.2**2])
    args = (c, J, torch.full((K,), 0.95), torch.zeros(K, 1), torch.full((K, 1, 1), 100.0), torch.eye(1), torch.zeros(1), cov)
    vis, pap = ForceTransport(*args, brush="visible"), ForceTransport(*args, brush="paper")
    q0 = torch.zeros(1, 1)
    pts = torch.tensor([[32.0, 4.0 + a] for a in (10.0, 20.0)])
    j_vis = vis.brush_jacobian(q0, pts, 1.0)[:, 0, 0]
    j_pap = pap.brush_jacobian(q0, pts, 1.0)[:, 0, 0]
    np.testing.assert_allclose(j_vis.numpy(), [10.0, 20.0], rtol=0.1)  # the brush edge reaches the background
    # the paper's brush is diluted by the background primitives behind the rod
    assert float((j_pap / torch.tensor([10.0, 20.0])).max()) < 0.85
    assert float((j_vis - j_pap).min()) > 1.0
    # off the rod, on the background: nothing moves with either brush
    far = torch.tensor([[10.0, 30.0]])
    assert float(vis.brush_jacobian(q0, far, 1.5).abs().max()) < 1e-6
    # select() and brush_jacobian() agree
    sel = vis.select(q0, pts[:1], 1.0)
    np.testing.assert_allclose(vis.pullback(sel, torch.tensor([[1.0, 0.0]])).numpy()[0, 0], float(j_vis[0]), rtol=1e-5)
    with pytest.raises(ValueError, match="unknown brush"):
        ForceTransport(*args, brush="nearest")


def test_visible_brush_touches_the_front_surface_not_what_shows_through_it():
    """A moving disc whose centre lets 20 % of the light through, over a static background primitive.

    Compositing gives the background primitive about a fifth of the colour at
    the disc's centre, so the brush that counts every composited primitive
    (``min_transmittance`` 0, the default) reports about 0.8 of the disc's
    motion; the front surface (``min_transmittance`` 0.5) is the disc alone.
    """
    c = torch.tensor([[32.0, 32.0], [32.0, 32.0]])  # index order is depth: the disc composites first
    J = torch.tensor([[[3.0], [0.0]], [[0.0], [0.0]]])
    cov = torch.stack([torch.eye(2) * 2.0**2, torch.eye(2) * 6.0**2])
    alpha = torch.tensor([0.8, 0.99])
    args = (c, J, alpha, torch.zeros(2, 1), torch.full((2, 1, 1), 100.0), torch.eye(1), torch.zeros(1), cov)
    q0, centre = torch.zeros(1, 1), torch.tensor([[32.0, 32.0]])
    front = ForceTransport(*args, min_transmittance=0.5).brush_jacobian(q0, centre, 0.5)[0, 0, 0]
    every = ForceTransport(*args).brush_jacobian(q0, centre, 0.5)[0, 0, 0]
    assert float(front) == pytest.approx(3.0, rel=1e-6)
    assert 0.7 * 3.0 < float(every) < 0.85 * 3.0
    # past the disc's edge the background is the front surface: it does not move
    edge = ForceTransport(*args, min_transmittance=0.5).brush_jacobian(q0, torch.tensor([[42.0, 32.0]]), 0.5)
    assert float(edge.abs().max()) < 1e-6
    with pytest.raises(ValueError, match="min_transmittance"):
        ForceTransport(*args, min_transmittance=1.5)


def test_observed_motion_is_the_rms_swing_of_the_selected_material():
    # the seesaw swinging by q(t) = 0.1 sin(t): the material at radius a moves by a q(t) px, rms a * 0.1 / sqrt(2)
    tr = _seesaw()
    q = 0.1 * torch.sin(torch.linspace(0, 2 * math.pi, 401)[:-1])[:, None]
    sel = tr.select(torch.zeros(2, 1), torch.tensor([[48.0, 32.0], [36.0, 32.0]]), 0.5)
    arm = tr.application_point(torch.zeros(2, 1), sel)[:, 0] - 32.0  # the selected radius, ~16 and ~4 px
    np.testing.assert_allclose(tr.observed_motion(sel, q).numpy(), (arm.abs() * 0.1 / math.sqrt(2)).numpy(), rtol=1e-4)
    still = tr.select(torch.zeros(1, 1), torch.tensor([[4.0, 4.0]]), 0.5)  # a background primitive
    assert float(tr.observed_motion(still, q)[0]) == 0.0
    assert float(tr.observed_motion(sel, q + 3.0)[0]) == pytest.approx(float(tr.observed_motion(sel, q)[0]), rel=1e-5)
    with pytest.raises(ValueError, match="training states"):
        tr.observed_motion(sel, q[:, 0])
