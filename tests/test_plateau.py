"""Stage 1's stop rule (lagsplat.train.plateau): loss and chart stalled, or the wall-time cap."""

from __future__ import annotations

import numpy as np

from lagsplat.train.plateau import Plateau, affine_r2


def test_affine_r2_sees_through_the_whitening():
    rng = np.random.default_rng(0)
    z = rng.normal(size=(64, 2))
    assert affine_r2(3.0 * z @ np.array([[1.0, 0.5], [0.0, 2.0]]) + 7.0, z) > 1 - 1e-12
    assert affine_r2(np.tanh(3 * z), z) < 0.99


def test_stops_only_when_loss_and_chart_both_stall():
    rng = np.random.default_rng(0)
    z = rng.normal(size=(32, 1))
    p = Plateau(patience=500, tol=0.01)
    assert p.check(250, 1.0, z) is None
    assert p.check(500, 0.5, z) is None
    assert p.check(750, 0.4, z) is None  # loss still falling by 60 % over 500 steps
    z_b = z + rng.normal(size=z.shape)
    assert p.check(1000, 0.399, z_b) is None  # the chart still moves
    why = p.check(1250, 0.398, 2 * z_b + 1)  # 0.5 % better than at step 750, and the same chart up to an affine map
    assert why is not None and why.startswith("plateau")


def test_patience_zero_never_stops_but_the_cap_does():
    z = np.zeros((8, 1)) + np.arange(8)[:, None]
    p = Plateau(patience=0)
    assert all(p.check(s, 1.0, z) is None for s in range(0, 5000, 250))
    assert Plateau(patience=0, max_seconds=1e-9).check(0, 1.0, z) == "wall-time cap"
