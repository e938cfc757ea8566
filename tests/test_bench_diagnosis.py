"""The blind diagnosis benchmark's gap of the d + 1 remedy (benchmarks/diagnosis.py, over_common_floor)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

from lagsplat.diagnose.refit import gap_reduction


@pytest.fixture(scope="module")
def bench():
    path = Path(__file__).resolve().parents[1] / "benchmarks" / "diagnosis.py"
    spec = importlib.util.spec_from_file_location("bench_diagnosis", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _gap(eps_I, eps_AE):
    return {"eps_q": 0.3, "eps_freq": 0.01, "envelope_decay_error": 0.2, "eps_I": eps_I, "eps_AE": eps_AE,
            "image_excess": None if eps_I is None else (eps_I - eps_AE) / eps_AE}  # fmt: skip


def test_a_remedy_that_lowers_the_floor_is_scored_over_the_lower_floor(bench) -> None:
    # a d = 2 autoencoder draws the second body (floor 5.1e-3 -> 1.9e-3) and the image error falls
    # from 1.01e-2 to 5.6e-3; over their own floors the ratio doubles (0.97 -> 1.95)
    before, after = _gap(1.01e-2, 5.1e-3), _gap(5.6e-3, 1.9e-3)
    assert gap_reduction(before, after)["image_excess"] < -0.9
    b, a = bench.over_common_floor(before, after)
    assert b["eps_AE_common"] == a["eps_AE_common"] == pytest.approx(1.9e-3)
    assert b["image_excess"] == pytest.approx((1.01e-2 - 1.9e-3) / 1.9e-3)
    assert a["image_excess"] == pytest.approx((5.6e-3 - 1.9e-3) / 1.9e-3)
    assert gap_reduction(b, a)["image_excess"] == pytest.approx(1 - 3.7 / 8.2)
    assert (b["eps_AE"], a["eps_AE"]) == (5.1e-3, 1.9e-3) and before["image_excess"] == pytest.approx(0.98, abs=0.01)  # inputs kept


def test_a_latent_only_gap_has_no_image_excess(bench) -> None:
    b, a = bench.over_common_floor(_gap(None, 1e-3), _gap(2e-3, 1e-3))
    assert b["image_excess"] is None and a["image_excess"] is None
    assert gap_reduction(b, a)["image_excess"] is None
