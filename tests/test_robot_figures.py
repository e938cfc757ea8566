"""The soft robot's figures (lagsplat.viz.robot): the body read off the decoder, the force panels, their equilibria."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from lagsplat.forces.transport import ForceTransport
from lagsplat.train.stage2 import Stage2Config
from lagsplat.viz.robot import force_panels, foreground, panel_equilibria, robot_body

pytestmark = pytest.mark.usefixtures("one_torch_thread")

SIZE = 32


def _hanging_bar() -> tuple[ForceTransport, np.ndarray]:
    """A bar hanging from a static clamp: q1 bends the whole bar sideways, q2 only its lower half.

    Primitives every pixel down x = 16 from y = 6 to 28 (lateral Jacobians growing from the clamp), a static
    clamp above; the image is drawn by OpenCV, not by the rasteriser.
    """
    ys = np.arange(6, 29, dtype=np.float32)
    bar = np.stack([np.full_like(ys, 16.0), ys], 1)
    clamp = np.array([[x, y] for x in range(12, 21) for y in (2.0, 3.0, 4.0)], np.float32)
    c = torch.as_tensor(np.concatenate([clamp, bar]))
    K = len(c)
    J = torch.zeros(K, 2, 2)
    J[len(clamp) :, 0, 0] = torch.as_tensor(4.0 * (ys - 6) / 22)
    J[len(clamp) :, 0, 1] = torch.as_tensor(4.0 * np.clip(ys - 17, 0, None) / 11)
    ft = ForceTransport(c, J, torch.ones(K), torch.zeros(K, 2), 1e3 * torch.eye(2).expand(K, 2, 2).clone(), torch.eye(2), torch.zeros(2), size=(SIZE, SIZE))
    img = np.full((SIZE, SIZE, 3), 40, np.uint8)
    cv2.rectangle(img, (12, 1), (20, 4), (120, 120, 130), -1)
    cv2.rectangle(img, (14, 5), (18, 28), (235, 235, 225), -1)
    return ft, img / 255.0


def test_the_body_runs_from_the_clamp_down_and_leaves_out_what_does_not_move() -> None:
    ft, img = _hanging_bar()
    assert foreground(img)[2, 16] > 0.15 and foreground(img)[20, 3] < 0.05  # the clamp is foreground, the border is not
    body = robot_body(ft, torch.zeros(1, 2), img, sigma=1.0)
    assert body.axis @ np.array([0.0, 1.0]) > 0.95  # from the clamp (top) down to the free end
    assert body.pixels[:, 1].min() >= 5  # the static clamp is not part of the body
    assert 6 <= body.base[1] <= 12 and 17 <= body.length <= 24
    np.testing.assert_allclose(body.point(1.0), [16.0, 27.5], atol=1.5)
    np.testing.assert_allclose(body.point(0.5), [16.0, body.base[1] + 0.5 * body.length], atol=1.5)


def test_the_panels_follow_the_segments() -> None:
    two, one = force_panels(2), force_panels(1)
    assert len(two) == 9 and len(one) == 7
    assert all(0.0 < s <= 1.0 and kind in ("lateral", "axial") and sign in (-1.0, 1.0) for _, fs in two + one for s, kind, sign in fs)
    assert [s for s, _, _ in two[-1][1]] == [0.5, 1.0]  # the opposed pair: the junction and the free end
    assert two[0][1][0][2] == -two[1][1][0][2]  # left and right are mirror panels


def test_a_push_moves_the_bar_its_way_and_an_axial_push_on_a_bar_that_only_bends_does_nothing() -> None:
    ft, img = _hanging_bar()
    torch.manual_seed(0)
    model = Stage2Config().build(2)
    model.init_energy_scales(2 * np.pi * 1.0, 0.01)
    q_op = model.loaded_equilibrium().float()
    body = robot_body(ft, q_op, img, sigma=1.0)
    panels = [("tip right", [(1.0, "lateral", 1.0)]), ("tip left", [(1.0, "lateral", -1.0)]), ("tip outwards", [(1.0, "axial", 1.0)])]
    q_eq, arrows, moved = panel_equilibria(model, ft, body, panels, q_op, None, 2.0, 1.0, 0.25)
    tip = [float((ft.application_point(q_eq[i : i + 1], arrows[i][0][0]) - ft.application_point(q_op, arrows[i][0][0]))[0, 0]) for i in range(3)]
    assert tip[0] > 0.05 and tip[1] < -0.05  # image x: right, then left
    assert moved[0] == pytest.approx(moved[1], rel=0.05)  # mirror forces, mirror response about the unloaded state
    assert moved[2] < 1e-3 * moved[0]
    np.testing.assert_allclose(arrows[0][0][1], [1.0, 0.0], atol=0.05)  # "right" for a body hanging down
