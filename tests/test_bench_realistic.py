"""The realistic suite's scoring (benchmarks/realistic.py): the diagnosis's verdict against the clip's effect, and the summary."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest


@pytest.fixture(scope="module")
def bench(load_benchmark):
    return load_benchmark("realistic")


def _report(results: Path, name: str, verdict: str, reduction: float | None = None) -> None:
    d = results / name / "diagnosis"
    d.mkdir(parents=True)
    rep = {"verdict": verdict, "verdict_text": verdict, "gap": {"reduction": {"eps_q": reduction}}}
    (d / "report.json").write_text(json.dumps(rep))


def test_a_hardening_spring_read_as_nothing_significant_counts_and_the_strict_reading_is_kept(bench, tmp_path) -> None:
    cases = {"spring_cart-cubic_stiffness-s0-128": ("none", True, False), "pendulum-cubic_stiffness-s1-128": ("cubic_stiffness", True, True),
             "spring_cart-coulomb-s0-128": ("none", False, False), "pendulum-none-s0-128": ("none", True, True),
             "pendulum-drift-s0-128": ("periodic_force", False, False),
             "spring_cart-cubic_stiffness-s1-128": ("none", False, False)}  # a softening spring must be named  # fmt: skip
    for name, (verdict, ok, exact) in cases.items():
        _report(tmp_path, name, verdict, 0.4)
        row = bench.diagnosis_of(name, tmp_path, 0, "", 1.0)
        assert (row["verdict"], row["diagnosis_ok"], row["diagnosis_exact"], row["gap_reduction_eps_q"]) == (verdict, ok, exact, 0.4), name
    assert bench.diagnosis_of("pendulum-none-s1-128", tmp_path, 1, "lagsplat diagnose: boom", 1.0)["diagnosis_status"] == "crashed"


def test_the_summary_counts_controls_gate_failures_and_names_short_clips(bench, tmp_path) -> None:
    base = {"status": "ok", "f_truth_hz": 1.0, "eps_freq_truth": 0.01, "wall_s": 100.0, "diagnosis_status": "ok", "train_periods": 3.0}
    rows = [
        {**base, "name": "pendulum-none-s0-128", "system": "pendulum", "gate_passed": True, "truth_effect": "none", "verdict": "coulomb", "diagnosis_ok": False},
        {**base, "name": "pendulum-coulomb-s0-128", "system": "pendulum", "gate_passed": True, "truth_effect": "coulomb", "verdict": "coulomb",
         "diagnosis_ok": True, "gap_reduction_eps_q": 0.6},
        {**base, "name": "spring_cart-drift-s0-128", "system": "spring_cart", "gate_passed": False, "truth_effect": "drift", "verdict": "cannot_diagnose",
         "diagnosis_ok": False},
    ]  # fmt: skip
    s = bench.gather(rows, tmp_path / "short.md", [])
    D = s["diagnosis"]
    assert D["top1"] == 0.5 and D["controls_flagged"] == 1 and D["n_controls"] == 1
    assert (D["failed_gate_read_cannot_diagnose"], D["n_failed_gate"]) == (1, 1) and D["median_gap_reduction_eps_q"] == 0.6
    md = (tmp_path / "short.md").read_text()
    assert md.startswith("# Realistic suite (MuJoCo-rendered clips) against the ground truth, training frames cut to 3 periods")
    assert json.loads((tmp_path / "short.json").read_text())["summary"]["n_clips"] == 3
    assert "Rows measured at commit unknown (3 rows)." in md  # rows without a recorded commit say so
    assert "true_control" not in D  # no --true-law reading, no line
    rows[0].update(verdict_true_control="none", true_control_ok=True)  # the selection with the control law as the model
    rows[1].update(verdict_true_control="coulomb", true_control_ok=True)
    O = bench.gather(rows, tmp_path / "short.md", [])["diagnosis"]["true_control"]
    assert O == {"n": 2, "top1": 1.0, "top1_pipeline": 0.5, "controls_flagged": 0, "n_controls": 1}
    assert "the diagnosis's top-1 is 100 % over the 2 1-DOF clips" in (tmp_path / "short.md").read_text()
    rows[0].update(commit="aaa", diagnosis_commit="bbb")  # a row whose diagnosis alone was rerun at a later commit
    rows[1].update(commit="aaa", diagnosis_commit="aaa")
    md = (bench.gather(rows, tmp_path / "short.md", []), (tmp_path / "short.md").read_text())[1]
    assert "Rows measured at commit aaa (2 rows), unknown (1 rows); diagnoses at commit aaa (1 rows), bbb (1 rows)." in md


def test_the_reading_after_the_diagnosis_takes_the_refit_only_where_its_held_out_check_confirmed(bench, tmp_path) -> None:
    d = tmp_path / "spring_cart-end_stop-s0-128" / "diagnosis"
    d.mkdir(parents=True)
    gap = {"reduction": {"eps_q": 0.5}, "after": {"f_sim_hz": 1.02}, "held_out_check": {"confirmed": True}}
    (d / "report.json").write_text(json.dumps({"verdict": "end_stop", "verdict_text": "end_stop", "gap": gap}))
    row = {"status": "ok", "f_truth_hz": 1.0, "f_sim_hz": 1.09, **bench.diagnosis_of("spring_cart-end_stop-s0-128", tmp_path, 0, "", 1.0)}
    assert row["refit_confirmed"] and bench.eps_freq_after_diagnosis(row) == pytest.approx(0.02)
    assert bench.eps_freq_after_diagnosis({**row, "refit_confirmed": False}) == pytest.approx(0.09)  # the Stage-2 model stays
    assert bench.eps_freq_after_diagnosis({k: v for k, v in row.items() if k != "refit_confirmed"}) is None  # scored before the reading existed
    _report(tmp_path, "pendulum-none-s0-128", "none")  # no refit: the Stage-2 model's frequency
    ctrl = {"status": "ok", "f_truth_hz": 2.0, "f_sim_hz": 2.1, **bench.diagnosis_of("pendulum-none-s0-128", tmp_path, 0, "", 1.0)}
    assert not ctrl["refit_confirmed"] and bench.eps_freq_after_diagnosis(ctrl) == pytest.approx(0.05)
    rows = [{**r, "name": n, "system": n.split("-")[0], "eps_freq_truth": 0.09, "wall_s": 1.0} for r, n in
            ((row, "spring_cart-end_stop-s0-128"), (ctrl, "pendulum-none-s0-128"))]  # fmt: skip
    A = bench.gather(rows, tmp_path / "r.md", [])["after_diagnosis"]
    assert A["n"] == 2 and A["eps_freq_truth_median"] == pytest.approx(0.035)


def test_the_truth_level_chart_is_split_where_the_pipeline_split_the_clip_and_whitened_on_its_training_frames(load_benchmark) -> None:
    latent = load_benchmark("diagnosis_latent")
    name = "spring_cart-none-s0-128"
    entry = next(e for e in latent.realistic_suite() if e["name"] == name)
    n_train = json.loads((latent.REPORTS / "realistic" / f"{name}.json").read_text())["n_train"]
    chart = latent.realistic_chart(entry, 0.0, 0)
    tr = chart.split == 0
    assert int(tr.sum()) == n_train and bool(tr[:n_train].all())
    assert abs(float(chart.q[tr].mean())) < 1e-12 and abs(float(chart.q[tr].std()) - 1.0) < 1e-12
    # the map is linear: the chart is the true coordinate up to scale and offset
    x = latent.motion_of(entry).q[:, 0]
    assert abs(abs(np.corrcoef(x, chart.q[:, 0])[0, 1]) - 1.0) < 1e-12
    noisy = latent.realistic_chart(entry, 0.05, 0)
    assert 0.03 < float(np.std(noisy.q[:, 0] - chart.q[:, 0])) < 0.07


def test_the_short_truth_level_chart_trains_on_three_periods_of_the_true_motion(load_benchmark) -> None:
    latent = load_benchmark("diagnosis_latent")
    entry = next(e for e in latent.realistic_suite() if e["name"] == "spring_cart-none-s0-128")
    motion = latent.motion_of(entry)
    chart = latent.realistic_chart(entry, 0.0, 0, train_periods=3.0)
    tr = chart.split == 0
    n = int(tr.sum())
    assert bool(tr[:n].all()) and not bool(tr[n:].any())
    x = motion.q[:n, 0]  # a free decay from a turning point: three periods hold six turning points, the seventh lies beyond
    turns = np.flatnonzero(np.sign(np.diff(x[1:])) != np.sign(np.diff(x[:-1])))
    assert abs(n * float(np.median(np.diff(motion.t))) * motion.f0_hz - 3.0) < 0.1
    assert len(turns) in (5, 6)


def test_the_gap_reduction_is_also_read_over_the_clips_whose_gap_stands_out_of_their_systems_controls(bench, tmp_path) -> None:
    base = {"status": "ok", "f_truth_hz": 1.0, "eps_freq_truth": 0.01, "wall_s": 100.0, "diagnosis_status": "ok", "gate_passed": True}

    def row(name: str, effect: str, eps_q: float, red: float | None) -> dict:
        system = name.split("-")[0]
        return {**base, "name": name, "system": system, "truth_effect": effect, "verdict": effect, "diagnosis_ok": True,
                "eps_q": eps_q, "gap_reduction_eps_q": red}  # fmt: skip

    rows = [
        row("pendulum-none-s0-128", "none", 0.05, None), row("pendulum-none-s1-128", "none", 0.066, None),
        row("pendulum-end_stop-s0-128", "end_stop", 0.37, 0.6),  # measurable
        row("pendulum-periodic_force-s0-128", "periodic_force", 0.14, 0.4),  # measurable
        row("pendulum-quadratic_drag-s0-128", "quadratic_drag", 0.06, -0.5),  # at the no-effect level; after 0.09 is above it
        row("pendulum-cubic_stiffness-s0-128", "cubic_stiffness", 0.053, 0.1),  # at the level; after 0.048 stays below
        row("spring_cart-end_stop-s0-128", "end_stop", 0.2, -0.9),  # no control of its system: left out
    ]  # fmt: skip
    D = bench.gather(rows, tmp_path / "r.md", [])["diagnosis"]
    assert D["median_gap_reduction_eps_q"] == pytest.approx(0.1)  # every refit: -0.9, -0.5, 0.1, 0.4, 0.6
    m = D["measurable_gap"]
    assert m["levels"] == {"pendulum": 0.066} and (m["n"], m["n_refit"], m["n_kept"]) == (2, 4, 1)
    assert m["median"] == pytest.approx(0.5)
    assert "measurable gap (held-out eps_q above the largest of the same system's controls: pendulum 0.066): median eps_q change after the refit +50 %" in (tmp_path / "r.md").read_text()


def test_a_clip_not_rendered_stops_before_any_stage_naming_the_missing_files(bench, tmp_path, capsys) -> None:
    row = tmp_path / "row.json"
    with pytest.raises(SystemExit) as e:
        bench.main(["--clip", "spring_cart-none-s0-128", "--clips", str(tmp_path), "--results", str(tmp_path / "res"), "--row", str(row)])
    err = capsys.readouterr().err
    assert e.value.code == 2 and "spring_cart-none-s0-128.truth.npz" in err and "python -m lagsplat.synth.realistic" in err
    assert not row.exists() and not (tmp_path / "res").exists()


def _true_law_clip(tmp_path: Path, f0_factor: float = 1.0, effect: str = "periodic_force"):
    """A pendulum with an unlogged periodic force (or ``effect``) seen through a bent chart, q = 3 x - 4 x^3 + noise, and its
    truth file (with the natural frequency scaled by ``f0_factor``: a wrong law)."""

    from lagsplat.chart import Chart
    from lagsplat.synth.effects import simulate_effect

    run = simulate_effect("pendulum", effect, seed=0, fps=30.0, duration_s=12.0, n_episodes=2)
    q = 3 * run.x - 4 * run.x**3 + 0.003 * np.random.default_rng(0).standard_normal(len(run.x))
    I = np.eye(1)
    chart = Chart(mean=np.zeros(1), W=I, W_inv=I, q=q[:, None], t=run.t, split=run.split, G_bar=I, A=I, ae_mse=np.zeros(len(q)),
                  ae_floor_train=0.0, ae_floor_held_out=0.0, height=64, width=64, episode=run.episode, u=run.u)  # fmt: skip
    truth = {**run.truth, "f0_hz": run.truth["f0_hz"] * f0_factor}
    path = tmp_path / f"clip-{effect}-{f0_factor}.truth.npz"
    np.savez(path, q=run.x[:, None], t=run.t, truth_json=json.dumps(truth))
    return chart, path


def test_the_true_law_in_a_bent_chart_scores_at_the_noise_and_a_wrong_law_does_not(bench, tmp_path) -> None:
    from _oracle import true_law_gap  # benchmarks/, on the path once the benchmark is loaded

    chart, path = _true_law_clip(tmp_path)
    right = true_law_gap(chart, path, "pendulum", floor_draws=2)
    assert abs(right["chart_map_rms"] - 0.003) < 0.001  # the cubic recovers the bend, leaving the noise
    wrong = true_law_gap(chart, _true_law_clip(tmp_path, 1.05)[1], "pendulum", floor_draws=2)
    assert right["eps_q"] < 0.05 and wrong["eps_q"] > 3 * right["eps_q"], (right, wrong)
    assert right["eps_q"] < 2 * right["eps_q_floor"] + 0.01  # what any model scores on this chart's noise, no more
    with pytest.raises(ValueError, match="1-D chart"):
        true_law_gap(type(chart)(**{**chart.__dict__, "q": chart.q.repeat(2, 1), "W": chart.W.repeat(2, 0).repeat(2, 1)}), path, "pendulum")


def test_the_selection_with_the_true_control_law_names_the_effect_and_nothing_on_a_control(bench, tmp_path) -> None:
    from _oracle import law_in_chart, true_control_diagnosis  # benchmarks/, on the path once the benchmark is loaded

    for effect, want in (("coulomb", "coulomb"), ("none", "none")):
        chart, path = _true_law_clip(tmp_path, effect=effect)
        d = true_control_diagnosis(chart, path, "pendulum")
        assert d.winner == want, (effect, [(f.effect, f.evidence, f.significant) for f in d.ranking])
        assert law_in_chart(chart, path, "pendulum", control=True)[0].truth["effect"] == "none"
    chart, path = _true_law_clip(tmp_path, effect="coulomb")
    assert law_in_chart(chart, path, "pendulum")[0].truth["effect"] == "coulomb"  # without control: the clip's own law
    z = dict(np.load(path))
    z["truth_json"] = json.dumps({**json.loads(str(z["truth_json"])), "actuated": True})
    np.savez(tmp_path / "actuated.truth.npz", **z)
    with pytest.raises(ValueError, match="actuated"):
        true_control_diagnosis(chart, tmp_path / "actuated.truth.npz", "pendulum")


def test_the_true_law_in_chart_coordinates_is_the_chain_rule_of_the_law(bench) -> None:
    import torch

    from _oracle import TrueLawInChart
    from lagsplat.synth.effects import simulate_effect, true_acceleration

    tr = simulate_effect("pendulum", "none", seed=0, fps=30.0, duration_s=4.0, n_episodes=2).truth
    coef = np.array([-4.0, 0.5, 3.0, 0.2])  # q = -4 x^3 + 0.5 x^2 + 3 x + 0.2
    m = TrueLawInChart(tr, coef, 8.0, time_channel=False)
    x = np.linspace(-0.3, 0.3, 7)
    xd = np.linspace(1.0, -0.5, 7)
    phi = np.poly1d(coef)
    q, qd = phi(x), phi.deriv()(x) * xd
    got = m.acceleration(torch.tensor(q[:, None]), torch.tensor(qd[:, None])).numpy()[:, 0]
    want = phi.deriv()(x) * true_acceleration(tr, 8.0)(0.0, x, xd) + phi.deriv(2)(x) * xd**2
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9)


def test_the_true_law_is_left_out_where_there_is_none_or_the_run_never_evaluated(bench, tmp_path) -> None:
    chart, _ = _true_law_clip(tmp_path)
    from lagsplat.artifacts import Artifacts
    from lagsplat.chart import save_chart

    save_chart(Artifacts.for_run(tmp_path, "pendulum-coulomb-s0-128").chart, chart)  # a chart, but the run stopped before evaluate
    assert bench.true_law_of("pendulum-coulomb-s0-128", tmp_path, tmp_path) == {}
    assert bench.true_law_of("spring_cart-missing_dof-s0-128", tmp_path, tmp_path) == {}  # two degrees of freedom: no 1-DOF law
