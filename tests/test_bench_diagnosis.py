"""The blind diagnosis benchmark's gap of the d + 1 remedy (benchmarks/diagnosis.py, over_common_floor)."""

from __future__ import annotations


import numpy as np
import pytest

from lagsplat.diagnose.gap import gap_reduction


@pytest.fixture(scope="module")
def bench(load_benchmark):
    return load_benchmark("diagnosis")


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


def _row(system, truth, before, after, refit=True):
    """A row of ``score`` for ``eps_freq`` only (the other metrics absent)."""
    from lagsplat.diagnose.refit import GAP_METRICS

    b = {k: None for k in GAP_METRICS} | {"eps_freq": before}
    a = {k: None for k in GAP_METRICS} | {"eps_freq": after}
    red = gap_reduction(b, a) if after is not None else {k: None for k in GAP_METRICS}
    return {"system": system, "truth": truth, "refit": refit, "before": b, "after": a} | {f"red_{k}": v for k, v in red.items()}


def test_only_gaps_above_the_same_systems_controls_count_towards_the_median(bench) -> None:
    rows = [
        _row("pendulum", "none", 0.002, None, refit=False),
        _row("pendulum", "none", 0.001, None, refit=False),
        _row("cart", "none", 0.004, None, refit=False),
        _row("pendulum", "drift", 0.06, 0.006),  # measurable (> 0.002): +90 %
        _row("pendulum", "end_stop", 0.03, 0.02),  # measurable: +33 %
        _row("pendulum", "coulomb", 0.0005, 0.002),  # at the no-effect level (-300 %); refit stays at it
        _row("pendulum", "quadratic_drag", 0.001, 0.003),  # at the level; refit goes above it
        _row("cart", "end_stop", 0.003, 0.0001),  # below the cart's level 0.004 (the pendulum's would have let it in)
        _row("cart", "drift", 0.05, 0.01),  # measurable: +80 %
        _row("two_carts", "drift", 0.05, 0.0),  # no control of its system: left out
        _row("pendulum", "periodic_force", 0.05, None),  # no after (refit failed): no reduction, left out
    ]
    for r, vs in zip(rows[3:6], (0.5, -0.2, 0.9)):  # against the fine-tune without the term; the third is not measurable
        r["red_ctrl_eps_freq"] = vs
    rows[8]["red_ctrl_eps_freq"] = 0.1
    m = bench.measurable_gap_medians(rows)["eps_freq"]
    assert m["median_vs_control"] == pytest.approx(0.1)  # median of 0.5, -0.2, 0.1
    assert m["levels"] == {"pendulum": 0.002, "cart": 0.004}
    assert (m["n"], m["n_refit"], m["n_kept"]) == (3, 6, 2)
    assert m["median"] == pytest.approx(0.8)
    # the second reading: (before - after) / (before - level) over the same three, none brought to the level
    assert m["median_excess_removed"] == pytest.approx((0.05 - 0.01) / (0.05 - 0.004))
    assert m["n_at_level"] == 0
    # the ceiling of refits that reach the level: 1 - level / before over the same three
    assert m["median_at_level"] == pytest.approx(np.median([1 - 0.002 / 0.06, 1 - 0.002 / 0.03, 1 - 0.004 / 0.05]))
    empty = bench.measurable_gap_medians([_row("cart", "none", 0.004, None, refit=False)])["eps_freq"]
    assert empty["median"] is None and empty["n"] == 0 and empty["median_excess_removed"] is None and empty["median_at_level"] is None


def test_the_share_of_the_excess_removed_stops_at_one_where_the_refit_reaches_the_no_effect_level(bench) -> None:
    """A gap 1.5x the level that the refit takes below it: the plain reduction reads +40 %, the excess is all removed."""
    rows = [_row("cart", "none", 0.02, None, refit=False), _row("cart", "coulomb", 0.03, 0.018), _row("cart", "end_stop", 0.06, 0.04)]
    m = bench.measurable_gap_medians(rows)["eps_freq"]
    assert m["n"] == 2 and m["n_at_level"] == 1
    assert m["median"] == pytest.approx(np.median([1 - 0.018 / 0.03, 1 - 0.04 / 0.06]))
    assert m["median_excess_removed"] == pytest.approx(np.median([1.0, 0.02 / 0.04]))


def test_gathered_rows_say_the_commit_they_were_measured_at(bench, tmp_path) -> None:
    """``--clip ... --row`` files carry the commit; ``--gather`` lists each commit with its count, and a row file
    written before rows held one as "not recorded", never as the current checkout."""
    import json
    from pathlib import Path

    src = Path(__file__).resolve().parents[1] / "results" / "benchmarks" / "diagnosis" / "cheap"
    paths = []
    for name, commit in (("pendulum-none-0", "abc1234"), ("cart-coulomb-0", None)):
        doc = json.loads((src / f"{name}.json").read_text())
        doc.pop("commit", None)
        if commit:
            doc["commit"] = commit
        paths.append(tmp_path / f"{name}.json")
        paths[-1].write_text(json.dumps(doc))
    rows, timings, budget = bench.read_rows([str(p) for p in paths])
    assert [r["commit"] for r in rows] == ["abc1234", "not recorded"] and budget == "cheap"
    text, record = bench.summarize(rows, timings, budget, markdown=True)
    assert "rows measured at commit: abc1234 (1 rows), not recorded (1 rows)" in text
    header = next(ln for ln in text.splitlines() if ln.startswith("| clip"))
    assert "commit" not in header  # not a column of the per-clip table


def test_a_hardening_spring_read_as_nothing_significant_is_counted_in_a_second_reading_only(bench) -> None:
    from pathlib import Path

    rows, timings, budget = bench.read_rows(sorted(str(p) for p in (Path(bench.__file__).parents[1] / "results/benchmarks/diagnosis/cheap").glob("*.json")))
    by = {r["clip"]: r for r in rows}
    for name, verdict in (("cart-cubic_stiffness-0", "none"), ("cart-cubic_stiffness-1", "none"), ("pendulum-cubic_stiffness-0", "cubic_stiffness")):
        by[name].update(verdict=verdict, ok=verdict == "cubic_stiffness")  # seed 0 hardening, seed 1 softening
    text, _ = bench.summarize(rows, timings, budget)
    strict = sum(r["ok"] for r in rows)
    assert f"top-1 accuracy: {strict / len(rows):.3f} ({strict}/{len(rows)})" in text  # the strict reading stays first
    assert f"({strict + 1}/{len(rows)}; cart-cubic_stiffness-0)" in text  # the softening spring read as none is not excused
