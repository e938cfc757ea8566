"""The projected wall time of the soft-robot chain (lagsplat.report.projection)."""

from __future__ import annotations

import numpy as np
import pytest

from lagsplat.cli_common import apply_variant, compose
from lagsplat.report.projection import COSTS, REAL_FRAMES, job_seconds, project, projection_lines


def _cfg(system: str, *extra: str):
    return apply_variant(compose([f"system={system}", "raw_dir=/nonexistent", *extra]))


def test_each_job_costs_its_budget_times_the_unit_cost() -> None:
    cfg = _cfg("krauss_2seg", "stage1.steps=1000", "stage1.batch=32", "stage2.epochs=10", "stage2.windows_per_epoch=320", "stage2.batch=32")
    assert job_seconds("stage1", cfg) == pytest.approx(1000 * COSTS["stage1_step"] * 2.0)  # batch 32, 2048 Gaussians
    assert job_seconds("stage2", cfg) == pytest.approx(100 * COSTS["stage2_step_learned"])
    assert job_seconds("chart", cfg) == pytest.approx(REAL_FRAMES["krauss_2seg"] * COSTS["chart_frame"])
    decoder = _cfg("krauss_2seg", "variant=mass_decoder", "stage2.epochs=10", "stage2.windows_per_epoch=320", "stage2.batch=32")
    assert job_seconds("stage2_variant", decoder) == pytest.approx(100 * COSTS["stage2_step_decoder"])  # priced by its own inertia form
    assert job_seconds("krauss_archive", cfg) == 0.0  # downloads are not projected


def test_the_frames_come_from_the_clip_on_disk(tmp_path) -> None:
    np.savez(tmp_path / "scr_dataset_raw_2seg_32x32_59fps.npz", images=np.zeros((1200, 3, 2, 2), np.uint8))
    cfg = apply_variant(compose(["system=krauss_2seg", f"raw_dir={tmp_path}"]))
    assert job_seconds("chart", cfg) == pytest.approx(1200 * COSTS["chart_frame"])
    synth = _cfg("krauss_2seg_synth")  # no file: the surrogate's length from its generator settings
    assert job_seconds("chart", synth) == pytest.approx(round(300.0 / float(synth.system.source.dt)) * COSTS["chart_frame"])


def test_systems_share_the_cores_and_a_chain_runs_in_order() -> None:
    one, two = _cfg("krauss_1seg"), _cfg("krauss_2seg")
    jobs = [(r, "krauss_1seg", one) for r in ("stage1", "chart", "stage2")] + [(r, "krauss_2seg", two) for r in ("stage1", "chart", "stage2")]
    p2, p1 = project(jobs, 2), project(jobs, 1)
    assert p2["wall_seconds"] == pytest.approx(max(p2["systems"].values()))
    assert p1["wall_seconds"] == pytest.approx(p1["job_seconds"]) == pytest.approx(sum(p2["systems"].values()))
    lines = projection_lines(p2)
    assert lines[0].startswith("[lagsplat] projected wall time") and len(lines) == 3
    assert projection_lines(project([], 2)) == []
