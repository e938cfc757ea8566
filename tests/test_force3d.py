"""Forces in 3-D: the ray meets the front material, world forces pull back through J_i [3,d], a push along the
viewing direction moves the object in depth."""

from types import SimpleNamespace

import pytest
import torch

from lagsplat.forces.transport3d import ForceTransport3D
from lagsplat.models.decoder3d import ConditionedGaussians3D
from lagsplat.models.lagrangian import Lagrangian
from lagsplat.render.camera import look_at, project_points

S = 32


def _scene():
    """Two primitives on the camera axis: a movable one in front (z = -0.3) whose latent q1 moves it along world x
    and q2 along world z (depth), and a static one behind (z = +0.5)."""
    cam = look_at((0.0, 0.0, -2.0), (0.0, 0.0, 0.0), (0.0, -1.0, 0.0), S, S, 40.0)
    dec = ConditionedGaussians3D(2, 2, cam, depth_range=(1.0, 3.0))
    n = 5
    L = torch.zeros(2, n, n)
    L[0] = torch.diag(torch.tensor([1.0, 1.0, 0.1, 0.1, 0.1]))  # the front one, about 2.6 px wide
    L[1] = torch.diag(torch.tensor([1.0, 1.0, 0.04, 0.04, 0.04]))
    L[0, 2, 0] = 0.2  # Sigma_sq: world x moves with z1 (J = L_sq L_qq^-1)
    L[0, 4, 1] = 0.3  # world z moves with z2
    L[1, 2:, :2] = 0.0
    raw = L[:, dec.tril_i, dec.tril_j].clone()
    diag = dec.tril_i == dec.tril_j
    raw[:, diag] = torch.log(torch.expm1(raw[:, diag] - 1e-4))
    with torch.no_grad():
        dec.L_raw.copy_(raw)
        dec.mu_raw.copy_(torch.tensor([[0.0, 0.0, -0.3], [0.0, 0.0, 0.5]]))
        dec.mu_q.zero_()
        dec.logit_alpha.fill_(5.0)
    ae = SimpleNamespace(decoder=dec, height=S, width=S)
    chart = SimpleNamespace(W_inv=torch.eye(2), mean=torch.zeros(2))
    return cam, ForceTransport3D.from_autoencoder(ae, chart, min_transmittance=0.5)


def test_the_ray_selects_the_front_material_and_its_world_jacobian():
    cam, ft = _scene()
    assert ft.J.shape == (2, 3, 2)
    torch.testing.assert_close(ft.J[0], torch.tensor([[0.2, 0.0], [0.0, 0.0], [0.0, 0.3]]), atol=1e-4, rtol=0)
    sel = ft.select(torch.zeros(1, 2), cam, torch.tensor([S / 2, S / 2]))
    assert float(sel.weights[0, 0]) > 0.99  # the front primitive; the one behind is hidden
    off = ft.select(torch.zeros(1, 2), cam, torch.tensor([1.0, 1.0]))  # a ray that meets nothing
    assert float(off.weights.abs().sum()) == 0.0


def test_a_push_along_the_viewing_direction_moves_the_object_in_depth():
    cam, ft = _scene()
    model = Lagrangian(2, "scalar", c0=0.1).eval()
    q_rest = model.loaded_equilibrium(None)
    x = torch.tensor([S / 2, S / 2])
    sel = ft.select(q_rest, cam, x)
    view = ft.viewing_direction(cam, x)
    torch.testing.assert_close(view, torch.tensor([0.0, 0.0, 1.0]), atol=1e-5, rtol=0)
    p0 = ft.application_point(q_rest, sel)
    for sign in (1.0, -1.0):
        f_lat = ft.pullback(sel, sign * 5.0 * view[None])
        assert abs(float(f_lat[0, 0])) < 1e-6 and float(sign * f_lat[0, 1]) > 0  # only the depth coordinate is pushed
        q = model.loaded_equilibrium(f_lat, q0=q_rest)
        p = ft.application_point(q, sel)
        (uv0, z0), (uv, z) = project_points(p0, cam), project_points(p, cam)
        assert float(sign * (z - z0)) > 1e-3  # pushed away from (or pulled towards) the camera
        assert float((uv - uv0).norm()) < 0.05 * float(sign * (z - z0)) * cam.fx  # and it stays under the pixel
    f_side = ft.pullback(sel, torch.tensor([[5.0, 0.0, 0.0]]))
    assert float(f_side[0, 0]) > 0 and abs(float(f_side[0, 1])) < 1e-6  # an image-plane push moves the other coordinate


def test_bad_use_is_refused():
    cam, ft = _scene()
    with pytest.raises(ValueError):
        ft.select(torch.zeros(2, 2), cam, torch.tensor([1.0, 1.0]))
    with pytest.raises(ValueError, match="3-D decoder"):
        from lagsplat.models.decoder import ConditionedGaussians

        ForceTransport3D.from_autoencoder(SimpleNamespace(decoder=ConditionedGaussians(2, 1), height=S, width=S), None)
