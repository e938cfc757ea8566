"""The projected wall time of the soft-robot chain and of the paper target (lagsplat.report.projection)."""

from __future__ import annotations

import numpy as np
import pytest

from lagsplat.cli_common import apply_variant, compose
from lagsplat.report.projection import COSTS, REAL_FRAMES, item_lines, job_seconds, project, project_items, projection_lines


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


def test_a_whole_run_and_the_decoder_comparison_are_priced_from_their_stages() -> None:
    toy = _cfg("toy")  # a procedural clip: its length from its parameters
    frames = round(float(toy.system.source.params.duration_s) * float(toy.system.source.params.fps))
    assert job_seconds("chart", toy) == pytest.approx(frames * COSTS["chart_frame"])
    chain = sum(job_seconds(r, toy) for r in ("ingest", "stage1", "chart", "stage2", "evaluate"))
    assert chain > 0 and job_seconds("seed_run", toy) == pytest.approx(chain)
    assert job_seconds("deformation_table", toy) == pytest.approx(job_seconds("stage1", toy))
    cart = _cfg("oscillating_cart")  # a video that is not on disk: per-frame jobs unpriced, Stage 1 priced
    assert job_seconds("chart", cart) == 0.0 and job_seconds("stage1", cart) > 0


def test_the_paper_items_share_the_cores_and_unpriced_rules_are_named() -> None:
    toy, cart = _cfg("toy"), _cfg("oscillating_cart")
    items = {
        "physical": [("stage1", "toy", toy, 2), ("stage2", "toy", toy, 2), ("stage1", "oscillating_cart", cart, 2), ("table", "None", None, 1)],
        "seeds": [("seed_run", "seed0/toy", toy, 2), ("seed_run", "seed1/toy", toy, 2)],
        "extrapolation": [("extrapolation", "toy", toy, 2)],
    }
    p = project_items(items, 2)
    s1, s2, run = job_seconds("stage1", toy), job_seconds("stage2", toy), job_seconds("seed_run", toy)
    assert p["items"] == pytest.approx({"physical": s1 + s2 + job_seconds("stage1", cart), "seeds": 2 * run, "extrapolation": 0.0})
    assert p["unpriced"] == {"table": 1, "extrapolation": 1}
    # two-thread jobs on two cores run one at a time: the wall time is every priced job in turn
    assert p["wall_seconds"] == pytest.approx(p["job_seconds"])
    one_thread = project_items({k: [(r, lane, c, 1) for r, lane, c, _ in v] for k, v in items.items()}, 2)
    assert one_thread["wall_seconds"] == pytest.approx(max(p["job_seconds"] / 2, s1 + s2))  # the cores shared, or the toy's chain
    lines = item_lines(p)
    assert lines[0].startswith("[lagsplat] projected wall time of the paper target on 2 core(s): at least ")
    assert [ln.split(":")[0].strip() for ln in lines[1:4]] == ["[lagsplat]   physical", "[lagsplat]   seeds", "[lagsplat]   extrapolation"]
    assert lines[3].endswith("nothing priced") and lines[4].endswith("extrapolation x1, table x1")
