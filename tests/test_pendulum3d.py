"""The 3-D test system (lagsplat.synth.pendulum3d): MuJoCo's renders agree with the cameras and the truth."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

import lagsplat.synth.realistic.camera  # noqa: F401  (sets MUJOCO_GL=egl before MuJoCo is imported)
from lagsplat.render.camera import load_cameras, project_points
from lagsplat.synth.pendulum3d import ROD_M, make_pendulum3d, pendulum3d_motion

mujoco = pytest.importorskip("mujoco")


def _bob_centre(img: np.ndarray) -> np.ndarray:
    """Centroid (px, pixel-centre convention) of the red bob in an RGB frame."""
    r, g, b = (img[..., i].astype(int) for i in range(3))
    ys, xs = np.nonzero((r > 120) & (r > 2 * g) & (r > 2 * b))
    assert len(xs) >= 5, "the bob is not in view"
    return np.array([xs.mean() + 0.5, ys.mean() + 0.5])


def test_the_truth_is_a_damped_pendulum_on_a_rod() -> None:
    m = pendulum3d_motion(fps=60.0, duration_s=4.0)
    assert m["f0_hz"] == pytest.approx(math.sqrt(9.81 / ROD_M) / (2 * math.pi))
    np.testing.assert_allclose(np.linalg.norm(m["bob"] - np.array([0.0, 0.0, 1.3]), axis=1), ROD_M, rtol=1e-9)
    energy = 0.5 * m["qdot"][:, 0] ** 2 + 9.81 / ROD_M * (1 - np.cos(m["q"][:, 0]))
    assert energy[-1] < energy[0] and np.all(np.diff(energy) <= 1e-9)  # damping only takes energy away


def test_every_camera_sees_the_bob_where_the_truth_projects(tmp_path) -> None:
    try:
        npz = make_pendulum3d(tmp_path / "p3d", fps=15.0, duration_s=1.4, size=64, n_views=3, noise_std=0.0)
    except RuntimeError as exc:  # no offscreen GL on this machine
        pytest.skip(str(exc))
    main = np.load(npz)["images"]
    views = np.load(tmp_path / "p3d.views.npz")["images"]
    truth = np.load(tmp_path / "p3d.truth.npz")
    cams = load_cameras(tmp_path / "p3d.cameras.json")
    assert main.shape == (21, 64, 64, 3) and views.shape == (21, 3, 64, 64, 3) and len(cams) == 4
    depths = []
    for i in range(0, 21, 4):
        for k, cam in enumerate(cams):
            img = main[i] if k == 0 else views[i, k - 1]
            uv, z = project_points(torch.as_tensor(truth["bob"][i : i + 1]), cam)
            assert np.linalg.norm(_bob_centre(img) - uv[0].numpy()) < 1.5, (i, k)
            if k == 0:
                depths.append(float(z[0]))
    assert max(depths) - min(depths) > 0.2  # the swing goes in depth for the main camera
