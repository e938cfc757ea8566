"""Pinhole cameras and the EWA projection of 3-D Gaussians (lagsplat.render.camera)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from lagsplat.render.camera import Camera, depth_order, load_cameras, look_at, orbit, project_gaussians, project_points, save_cameras


def _cam() -> Camera:
    return look_at(eye=(0.3, -0.2, -2.0), target=(0.0, 0.0, 0.5), up=(0.0, -1.0, 0.0), width=64, height=48, fov_y_deg=50.0)


def test_points_project_as_K_times_R_t() -> None:
    cam = _cam()
    X = torch.as_tensor(np.random.default_rng(0).normal(0, 0.3, (50, 3)) + [0, 0, 0.5])
    uv, z = project_points(X, cam)
    h = (cam.K @ (np.asarray(cam.R) @ X.numpy().T + np.asarray(cam.t)[:, None])).T
    np.testing.assert_allclose(uv.numpy(), h[:, :2] / h[:, 2:], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(z.numpy(), h[:, 2], rtol=1e-12)


def test_look_at_puts_the_target_at_the_centre_and_up_at_the_top() -> None:
    cam = _cam()
    uv, z = project_points(torch.tensor([[0.0, 0.0, 0.5], [0.0, -0.1, 0.5]], dtype=torch.float64), cam)
    np.testing.assert_allclose(uv[0].numpy(), [32.0, 24.0], atol=1e-9)
    assert uv[1, 1] < uv[0, 1] and z[0] > 0  # world -y ("up") is towards the top of the image, in front of the camera
    np.testing.assert_allclose(np.linalg.norm(cam.center - [0.3, -0.2, -2.0]), 0.0, atol=1e-12)


def test_the_ewa_covariance_is_the_covariance_of_projected_samples() -> None:
    cam = _cam()
    mu = torch.tensor([0.1, 0.05, 0.6], dtype=torch.float64)
    A = torch.tensor([[0.02, 0.0, 0.0], [0.01, 0.015, 0.0], [0.0, 0.005, 0.03]], dtype=torch.float64)
    cov = A @ A.T
    m2, c2, depth = project_gaussians(mu[None], cov[None], cam)
    X = mu + torch.as_tensor(np.random.default_rng(1).normal(size=(200_000, 3))) @ A.T
    uv, _ = project_points(X, cam)
    np.testing.assert_allclose(np.cov(uv.numpy().T), c2[0].numpy(), rtol=0.03)  # first order in (size / depth)
    np.testing.assert_allclose(uv.mean(0).numpy(), m2[0].numpy(), atol=0.02)
    assert float(depth[0]) > 2.0


def test_an_isotropic_gaussian_on_the_axis_projects_to_f_s_over_z() -> None:
    cam = look_at((0, 0, 0), (0, 0, 1), (0, -1, 0), 32, 32, 60.0)
    for z in (1.0, 2.0, 4.0):
        m2, c2, _ = project_gaussians(torch.tensor([[0.0, 0.0, z]]), 0.05**2 * torch.eye(3)[None], cam)
        np.testing.assert_allclose(c2[0].numpy(), (cam.fx * 0.05 / z) ** 2 * np.eye(2), rtol=1e-5)
        np.testing.assert_allclose(m2[0].numpy(), [16.0, 16.0], atol=1e-5)


def test_an_orbit_circles_the_target_and_looks_at_it() -> None:
    cams = orbit((0.0, 0.0, 1.0), radius=2.0, elevation_deg=20.0, n=8, width=32, height=32)
    centres = np.stack([c.center for c in cams])
    np.testing.assert_allclose(np.linalg.norm(centres - [0, 0, 1], axis=1), 2.0, rtol=1e-9)
    assert len({tuple(np.round(c, 6)) for c in centres}) == 8
    for c in cams:
        uv, z = project_points(torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64), c)
        np.testing.assert_allclose(uv[0].numpy(), [16.0, 16.0], atol=1e-9)
        assert float(z[0]) == pytest.approx(2.0)


def test_depth_order_sorts_front_to_back_and_keeps_ties_in_index_order() -> None:
    depth = torch.tensor([[3.0, 1.0, 2.0, 1.0]])
    vals = torch.arange(4.0)[None]
    cov = torch.arange(16.0).reshape(1, 4, 2, 2)
    v, c, order = depth_order(depth, vals, cov)
    assert order.tolist() == [[1, 3, 2, 0]] and v.tolist() == [[1.0, 3.0, 2.0, 0.0]]
    assert torch.equal(c[0, 0], cov[0, 1]) and torch.equal(c[0, 3], cov[0, 0])


def test_cameras_round_trip_and_a_bad_record_is_named(tmp_path) -> None:
    cams = orbit((0, 0, 1), 2.0, 10.0, 3, 40, 30)
    path = save_cameras(tmp_path / "cams.json", cams)
    assert load_cameras(path) == cams
    bad = [c.to_dict() for c in cams]
    del bad[1]["fx"]
    path.write_text(json.dumps(bad))
    with pytest.raises(ValueError, match=r"cams.json: camera 1: .*fx"):
        load_cameras(path)
    bad[1] = {**cams[1].to_dict(), "R": [[1, 0, 0], [0, 1, 0], [0, 0, 2]]}
    path.write_text(json.dumps(bad))
    with pytest.raises(ValueError, match=r"camera 1: R must be a 3x3 rotation"):
        load_cameras(path)
    path.write_text("{}")
    with pytest.raises(ValueError, match="expected a JSON list"):
        load_cameras(path)


def test_the_nearer_gaussian_covers_the_farther_one_whatever_their_index() -> None:
    from lagsplat.render.rasterize import rasterize

    cam = look_at((0, 0, 0), (0, 0, 1), (0, -1, 0), 24, 24, 60.0)
    mu = torch.tensor([[[0.0, 0.0, 2.0], [0.0, 0.0, 1.0]]])  # index 0 (blue) is behind index 1 (red)
    m2, c2, depth = project_gaussians(mu, (0.1**2 * torch.eye(3)).expand(1, 2, 3, 3), cam)
    colors = torch.tensor([[[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]])
    opac = torch.full((1, 2), 0.99)
    unsorted = rasterize(m2, c2, opac, colors, 24, 24, backend="torch")[0, :, 12, 12]
    m2, c2, opac, colors, _ = depth_order(depth, m2, c2, opac, colors)
    centre = rasterize(m2, c2, opac, colors, 24, 24, backend="torch")[0, :, 12, 12]
    assert unsorted[2] > 2 * unsorted[0]  # in index order the far one would be drawn on top
    assert centre[0] > 0.85 and centre[2] < 0.1


def test_an_orbit_through_a_camera_keeps_its_distance_and_an_arc_stays_on_the_filmed_side():
    from lagsplat.render.camera import orbit_through

    target = np.array([0.0, 0.0, 1.0])
    main = look_at((0.0, -0.5, -2.0), target, (0.0, -1.0, 0.0), 32, 32)
    side = [look_at((2.0 * np.sin(a), -0.5, 1.0 - 3.0 * np.cos(a)), target, (0.0, -1.0, 0.0), 32, 32) for a in (-0.6, 0.4)]
    full = orbit_through(main, target, 8)
    r = np.linalg.norm(main.center - target)
    assert np.allclose([np.linalg.norm(c.center - target) for c in full], r) and np.allclose(full[0].center, main.center, atol=1e-6)
    arc = orbit_through(main, target, 12, span=side)

    def azimuth(p):  # about the vertical through the target, 0 on the main camera's side
        return np.degrees(np.arctan2(p[0] - target[0], target[2] - p[2]))

    az = np.array([azimuth(c.center) for c in arc])
    assert np.allclose([np.linalg.norm(c.center - target) for c in arc], r)
    assert az.min() == pytest.approx(azimuth(side[0].center), abs=0.5) and az.max() == pytest.approx(azimuth(side[1].center), abs=0.5)
