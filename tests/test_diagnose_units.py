"""The identified motion in physical units (lagsplat.diagnose.units): a known length in the image, a pendulum's length."""

import math
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from lagsplat.diagnose.units import G, metres_per_source_px, motion_amplitude_source_px, physical_quantities


def _kinematics():
    from lagsplat.diagnose.screen import ScreenKinematics
    from lagsplat.forces.transport import ForceTransport

    c = torch.tensor([[10.0, 20.0], [12.0, 20.0], [14.0, 20.0], [30.0, 30.0], [31.0, 30.0], [32.0, 30.0]])
    J = torch.zeros(6, 2, 1)
    J[:3, 0, 0] = 2.0  # the object moves 2 working px in x per chart unit; the background does not move
    K = len(c)
    return ScreenKinematics(ForceTransport(c, J, torch.ones(K), torch.zeros(K, 1), 1e3 * torch.ones(K, 1, 1), torch.eye(1), torch.zeros(1)))


def test_a_known_length_in_the_image_gives_metres_per_pixel_and_a_bad_one_is_named():
    assert metres_per_source_px({"points": [0, 0, 300, 400], "metres": 1.0}) == pytest.approx(1 / 500)
    assert metres_per_source_px(None) is None and metres_per_source_px({"pendulum_length_m": 0.5}) is None
    with pytest.raises(ValueError, match="coincide"):
        metres_per_source_px({"points": [5, 5, 5, 5], "metres": 1.0})
    with pytest.raises(ValueError, match="both points"):
        metres_per_source_px({"metres": 1.0})


def test_the_amplitude_is_half_the_largest_swing_in_source_pixels():
    # the chart swings between -1.5 and +2.5 (4 units, 8 working px in x); the working frame is 48 px wide for 96 source px
    q = np.array([0.0, 2.5, -1.5, 1.0])[:, None]
    chart = SimpleNamespace(q=q, G_bar=np.eye(1))
    amp = motion_amplitude_source_px(_kinematics(), chart, {"crop": [0, 0, 96, 64], "resize": [48, 32]})
    assert amp == pytest.approx(0.5 * 8 * 2)
    assert motion_amplitude_source_px(_kinematics(), chart, None) == pytest.approx(4.0)  # no crop: working px


def test_physical_quantities_carry_the_frequency_interval_and_compare_a_pendulum_length():
    f, iv = 0.5, [0.49, 0.51]
    m = {"f_sim_hz": {"value": f}, "f_sim_hz_interval": {"value": iv}}
    rows = {r["quantity"].split(" (")[0].split(" =")[0]: r for r in physical_quantities(m, None, None)}
    km = rows["stiffness-to-mass ratio k/m"]
    assert km["value"] == pytest.approx((2 * math.pi * f) ** 2) and km["interval"] == pytest.approx([(2 * math.pi * x) ** 2 for x in iv])
    L = rows["length of the simple pendulum of this frequency g/(2 pi f)^2"]
    assert L["value"] == pytest.approx(G / (2 * math.pi * f) ** 2)
    assert L["interval"][0] < L["value"] < L["interval"][1]  # the higher frequency gives the shorter length
    assert "amplitude" not in rows  # no scale: no metres
    L_true = G / (2 * math.pi * f) ** 2
    scaled = physical_quantities(m, {"points": [0, 0, 100, 0], "metres": 0.2, "pendulum_length_m": L_true}, 50.0)
    by = {r["quantity"]: r for r in scaled}
    assert by["amplitude"]["value"] == pytest.approx(0.1)  # 50 px at 2 mm per px
    assert by["amplitude (angle)"]["value"] == pytest.approx(math.degrees(0.1 / L_true))
    assert by["implied over given pendulum length"]["value"] == pytest.approx(1.0)
