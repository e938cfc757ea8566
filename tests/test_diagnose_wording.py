"""The diagnosis report says only what its numbers support (lagsplat.diagnose.report_checks, markdown, refit_choice).

Each case is one the report got wrong on a real or independently rendered clip: a refit
"confirmed" by a 0.005 % change, an amplitude "lost" by 191 %, a caution about the training
motion printed for a model that follows it, and a rival with a Stage-2 remedy never refit
because the winner (a missing degree of freedom) has none.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest

import lagsplat.diagnose.refit_choice as refit_choice
from lagsplat.chart import Chart
from lagsplat.diagnose.diagnosis import CandidateFit, Diagnosis
from lagsplat.diagnose.gap import gap_reduction
from lagsplat.diagnose.markdown import render_markdown
from lagsplat.diagnose.report_checks import held_out_check, reliability


def _gap(before: dict, after: dict, control: dict | None, sd: float | None = None) -> dict:
    before = {**before, "floor": {"eps_q": 0.01, "eps_q_sd": sd}} if sd is not None else before
    return {"before": before, "after": after, "control": control, "reduction": gap_reduction(before, after),
            "reduction_vs_control": gap_reduction(control, after) if control else None}  # fmt: skip


def test_a_refit_is_confirmed_only_beyond_the_noise() -> None:
    before, ctrl = {"eps_q": 0.1, "image_excess": 1.0}, {"eps_q": 0.1, "image_excess": 1.0}
    tiny = {"eps_q": 0.1 * (1 - 5e-5), "image_excess": 0.5}  # eps_q moved by 0.005 %: printed "+0 %"
    check = held_out_check(_gap(before, tiny, ctrl), ["coulomb"])
    assert not check["confirmed"] and "does not shrink the held-out gap beyond the chart noise" in check["text"]
    five = {"eps_q": 0.095, "image_excess": 0.5}  # 5 % better, a change of 0.005 ...
    assert not held_out_check(_gap(before, five, ctrl, sd=0.004), ["coulomb"])["confirmed"]  # ... within 2 sd of the floor
    assert held_out_check(_gap(before, five, ctrl, sd=0.001), ["coulomb"])["confirmed"]  # ... beyond it
    assert held_out_check(_gap(before, five, None, sd=0.001), ["coulomb"])["confirmed"]  # no control fine-tune: against before only


def test_the_held_out_check_names_what_each_change_is_against() -> None:
    """Two numbers per metric: the change against the identified model and against the control fine-tune (whose own
    change is not printed), each named, so that neither reads as the other."""
    before, ctrl, after = {"eps_q": 0.4, "image_excess": 2.0}, {"eps_q": 0.5, "image_excess": 2.0}, {"eps_q": 0.2, "image_excess": 1.0}
    text = held_out_check(_gap(before, after, ctrl, sd=0.001), ["end_stop"])["text"]
    assert "eps q +50 % against the identified model, +60 % against the same fine-tune without the term" in text, text
    text = held_out_check(_gap(before, after, None, sd=0.001), ["end_stop"])["text"]
    assert "eps q +50 % against the identified model" in text and "without the term" not in text, text


def _report(envelope: dict, cautions: list[str] | None = None) -> dict:
    gap = {"eps_q": 0.1, "eps_freq": 0.01, "envelope_decay_error": 0.4, "image_excess": 1.0, "envelope": envelope}
    return {
        "title": "t", "system": "s", "verdict": "none", "verdict_text": "nothing significant",
        "reliability": {"reliable": True, "checks": {}, "reasons": [], "cautions": cautions or []},
        "diagnosis": {"null": {"excess_over_noise": 1.2}, "effects": [], "ranking": [], "evidence": {},
                      "settings": {"min_delta_bic": 10.0, "min_r2": 0.1, "min_cv_gain": 0.02}},
        "where": {"notes": []},
        "gap": {"definition": {"frames": "held-out frames"}, "before": gap, "after": None, "control": None, "reduction": None, "reduction_vs_control": None},
        "refit": {"done": False, "reason": "nothing significant"}, "config": {"refit": {"init": "fitted", "epochs": 40, "floor_scale": 4.0}},
        "frames": {"diagnosis_split": "train", "n_diagnosis_frames": 10, "n_held_out_frames": 5, "held_out_used_for": "the gap only"},
    }  # fmt: skip


def test_the_envelope_line_says_gain_loss_or_rest() -> None:
    md = render_markdown(_report({"form": "exponential", "decay_encoded": -0.25, "reliable": True}))
    assert "the encoded held-out video gains 25 % of its amplitude" in md
    md = render_markdown(_report({"form": "linear", "decay_encoded": 1.0, "reliable": True}))
    assert "loses 100 % (it comes to rest) of its amplitude" in md
    md = render_markdown(_report({"form": "linear", "decay_encoded": 0.4, "reliable": True}))
    assert "loses 40 % of its amplitude" in md and "comes to rest" not in md


def test_a_linear_envelope_never_decays_by_more_than_all_of_it() -> None:
    """A linear fit crosses zero before the segment ends when the motion stops (the '191 %' of a real cart)."""
    from lagsplat.diagnose.gap import envelope_decay
    from lagsplat.diagnose.oscillator import LinearOscillator
    from lagsplat.io.clip import HELD_OUT

    dt, n = 1 / 30, 300
    t = np.arange(n) * dt
    amp = np.maximum(1.0 - t / 4.0, 0.0)  # linear decay to rest at 4 s of a 10 s segment
    q = (amp * np.cos(2 * np.pi * 0.8 * t))[:, None]
    I = np.eye(1)
    chart = Chart(mean=np.zeros(1), W=I, W_inv=I, q=q, t=t, split=np.full(n, HELD_OUT, np.int8), G_bar=I, A=I, ae_mse=np.zeros(n),
                  ae_floor_train=0.0, ae_floor_held_out=0.0, height=8, width=8)  # fmt: skip
    w = 2 * np.pi * 0.8
    model = LinearOscillator(np.array([[w * w]]), np.array([[0.5]]), np.zeros(1))
    env = envelope_decay(chart, model)
    assert env["form"] == "linear" and env["decay_encoded"] == pytest.approx(1.0)


def test_a_caution_says_what_failed() -> None:
    q = np.sin(np.linspace(0, 20, 400))[:, None]
    I = np.eye(1)
    chart = Chart(mean=np.zeros(1), W=I, W_inv=I, q=q, t=np.arange(400) / 30.0, split=np.zeros(400, np.int8), G_bar=I, A=I,
                  ae_mse=np.zeros(400), ae_floor_train=1e-3, ae_floor_held_out=0.0, height=8, width=8,
                  meta={"gate": {"passed": True, "reasons": []}})  # fmt: skip
    diag = Diagnosis("none", [], [], {"excess_over_noise": 9.0, "excess_after_effects": 9.0, "unexplained": True}, {}, {}, {"unexplained_excess": 4.0})
    rel = reliability(chart, {"selected_nrmse": 0.11}, diag)
    assert rel["reliable"] and len(rel["cautions"]) == 1
    assert "residual stays well above the chart noise" in rel["cautions"][0] and "misses much of the training motion" not in rel["cautions"][0]
    md = render_markdown({**_report({}), "reliability": rel})
    assert "misses much of the training motion" not in md and "residual stays well above the chart noise" in md
    rel = reliability(chart, {"selected_nrmse": 0.8}, None)
    assert rel["cautions"] and "misses much of the training motion" in rel["cautions"][0]


def _fit(effect: str, delta_bic: float) -> CandidateFit:
    f = CandidateFit(effect, {}, np.ones(1), ["c"], np.ones(1), np.full(1, 0.1), 1.0, 1, 0.0, delta_bic=delta_bic, r2=0.3, cv_gain=0.3)
    f.significant = True
    return f


class _Refit:
    def __init__(self, nrmse: float) -> None:
        self.history = {"selected_nrmse": nrmse}


def test_a_rival_of_a_missing_dof_with_a_remedy_is_refit(monkeypatch) -> None:
    """Delta BIC 10.8 (missing dof) against 10.0 (end stop): the residual cannot tell them apart, the refit decides."""
    dof, stop = _fit("missing_dof", 10.8), _fit("end_stop", 10.0)
    diag = Diagnosis("missing_dof", [dof], [dof, stop], {}, {}, {}, {"min_delta_bic": 10.0})
    refit_nrmse = {"value": 0.1}
    seen: list[str] = []

    def fake_refit(chart, model, cfg, d, rc, inertia=None):
        seen.append(d.winner)
        assert rc.control is False
        return _Refit(refit_nrmse["value"])

    monkeypatch.setattr(refit_choice, "refit", fake_refit)
    chosen, rows, made = refit_choice.choose_by_refit(None, None, None, diag, 0.2)
    assert seen == ["end_stop"] and chosen.winner == "end_stop" and chosen.effects == [stop] and made is not None
    assert [(r["effect"], r["chosen"]) for r in rows] == [("missing_dof", False), ("end_stop", True)]
    md_line = render_markdown({**_report({}), "verdict": "end_stop", "refit": {"done": False, "reason": "x", "choice": rows,
                                                                              "baseline_train_rollout_nrmse": 0.2}})
    assert "has no Stage-2 refit, and the residual cannot tell it from end_stop" in md_line and "so end_stop is taken" in md_line
    refit_nrmse["value"] = 0.3  # its refit follows the training video worse than the identified model
    chosen, rows, made = refit_choice.choose_by_refit(None, None, None, diag, 0.2)
    assert chosen is diag and made is None and [r["chosen"] for r in rows] == [True, False]
    far = Diagnosis("missing_dof", [dof], [dof, _fit("end_stop", 5.0)], {}, {}, {}, {"min_delta_bic": 10.0})
    seen.clear()
    assert refit_choice.choose_by_refit(None, None, None, far, 0.2) == (far, [], None) and seen == []  # clearly behind: not refit
    assert copy.deepcopy(rows)  # the rows are plain data (report.json)


def test_a_held_out_part_too_short_for_the_gap_leaves_the_diagnosis_standing(tmp_path) -> None:
    """The diagnosis reads the training frames only: a held-out segment too short to score is said, not fatal."""
    from lagsplat.diagnose import fit_linear_oscillator
    from lagsplat.diagnose.report import diagnose_artifacts
    from lagsplat.io.clip import HELD_OUT, TRAIN

    dt, n, n_train = 1 / 30, 330, 300
    t = np.arange(n) * dt
    q = (np.exp(-0.1 * t) * np.cos(2 * np.pi * 0.8 * t) + 0.01 * np.random.default_rng(0).standard_normal(n))[:, None]
    split = np.where(np.arange(n) < n_train, TRAIN, HELD_OUT).astype(np.int8)  # 1 s held out: two periods need 2.5 s
    I = np.eye(1)
    chart = Chart(mean=np.zeros(1), W=I, W_inv=I, q=q, t=t, split=split, G_bar=I, A=I, ae_mse=np.zeros(n), ae_floor_train=0.0,
                  ae_floor_held_out=0.0, height=8, width=8, meta={"gate": {"passed": True, "reasons": []}})  # fmt: skip
    model = fit_linear_oscillator([q[:n_train]], dt)
    rep = diagnose_artifacts(None, None, chart, model, None, tmp_path / "diagnosis", system="short")
    assert rep["verdict"] == "none" and "held-out segment" in rep["gap"]["unavailable"]
    assert rep["refit"]["reason"].startswith("no held-out gap to score a refit on")
    md = (tmp_path / "diagnosis" / "report.md").read_text()
    assert "Not measured: " in md and "stands without it" in md


def test_an_effect_size_in_pixels_of_the_video() -> None:
    """Through the decoder's kinematics (mu_i(q) = c_i + J_i q): a stop's position and the friction's loss per cycle in px."""
    import torch

    from lagsplat.diagnose.pixels import add_pixel_sizes, object_position_px, px_per_unit, to_source_px
    from lagsplat.diagnose.screen import ScreenKinematics
    from lagsplat.forces.transport import ForceTransport

    c = torch.tensor([[10.0, 20.0], [12.0, 20.0], [14.0, 20.0], [30.0, 30.0], [31.0, 30.0], [32.0, 30.0]])
    J = torch.zeros(6, 2, 1)
    J[:3, 0, 0] = 2.0  # the object moves 2 px in x per chart unit; the background does not move
    K = len(c)
    tr = ScreenKinematics(ForceTransport(c, J, torch.ones(K), torch.zeros(K, 1), 1e3 * torch.ones(K, 1, 1), torch.eye(1), torch.zeros(1)))
    assert object_position_px(tr, np.array([1.5])) == pytest.approx([15.0, 20.0], abs=1e-4)
    assert px_per_unit(tr, np.array([1.0])) == pytest.approx(2.0)
    meta = {"crop": [40, 8, 110, 101], "resize": [48, 64]}
    assert to_source_px(np.array([15.0, 20.0]), meta) == pytest.approx([40 + 15 * 70 / 48, 8 + 20 * 93 / 64])
    assert to_source_px(np.array([1.0, 1.0]), {}) is None
    stop = CandidateFit("end_stop", {}, np.ones(1), ["k_stop"], np.ones(1), np.ones(1), 1.0, 1, 0.0, interpretation={"s_stop": 1.5, "text": "one-sided stop"})
    fric = CandidateFit("coulomb", {}, np.ones(1), ["mu"], np.ones(1), np.ones(1), 1.0, 1, 0.0, interpretation={"amplitude_loss_per_cycle": 0.5, "text": "dry friction"})
    add_pixel_sizes(Diagnosis("end_stop", [stop, fric], [], {}, {}, {}, {}), tr, meta)
    assert stop.interpretation["in_pixels"]["stop_xy_px"] == pytest.approx([15.0, 20.0], abs=1e-4)
    assert "the object touches the stop at (15, 20) px of the working frame, (62, 37) px of the source video" in stop.interpretation["text"]
    assert fric.interpretation["in_pixels"]["amplitude_loss_per_cycle_px"] == pytest.approx(1.0) and "(1.0 px of motion per cycle)" in fric.interpretation["text"]


def test_a_rival_far_behind_the_winner_is_not_refit(monkeypatch) -> None:
    """The refit's rollout error arbitrates only between candidates the residual does not separate by very strong evidence."""
    stop, drift = _fit("end_stop", 93.0), _fit("drift", 48.0)
    diag = Diagnosis("end_stop", [stop], [stop, drift], {}, {}, {}, {"min_delta_bic": 10.0})
    seen: list[str] = []
    monkeypatch.setattr(refit_choice, "refit", lambda chart, model, cfg, d, rc, inertia=None: (seen.append(d.winner), _Refit(0.5))[1])
    assert refit_choice.choose_by_refit(None, None, None, diag, 0.2) == (diag, [], None) and seen == []
    close = Diagnosis("end_stop", [stop], [stop, _fit("drift", 85.0)], {}, {}, {}, {"min_delta_bic": 10.0})
    chosen, rows, _ = refit_choice.choose_by_refit(None, None, None, close, 0.2)
    assert seen == ["end_stop", "drift"] and [r["effect"] for r in rows] == ["end_stop", "drift"]


def test_the_image_line_says_whether_the_scene_moves_beyond_the_chart() -> None:
    from lagsplat.diagnose.reading import distinguishing_lines

    def dg(sup, dbic=33.0):
        mode = {"effect": "missing_dof", "delta_bic": dbic, "evidence": dbic, "physical": True, "params": {"f_hz": 1.216},
                "interpretation": {"image_error_support": sup}}  # fmt: skip
        return {"evidence": {}, "settings": {"min_delta_bic": 10.0}, "ranking": [mode]}

    seen = [ln for ln in distinguishing_lines(dg(106.0)) if ln.startswith("- image:")]
    assert seen == ["- image: the autoencoder's per-frame error oscillates at the hidden mode's 1.22 Hz beyond what the encoded state "
                    "explains (evidence 106): part of the scene moves in a way the chart does not carry, a mode rather than a force"]  # fmt: skip
    unseen = [ln for ln in distinguishing_lines(dg(-23.0)) if ln.startswith("- image:")]
    assert len(unseen) == 1 and "differ here only in their decay" in unseen[0]
    assert not [ln for ln in distinguishing_lines(dg(106.0, dbic=4.0)) if ln.startswith("- image:")]  # no mode found: no question


def _decay_law_lines(law: dict) -> list[str]:
    """The report's whole-trajectory decay lines for a ``decay_law`` record."""
    from lagsplat.diagnose.reading import distinguishing_lines

    dg = {"evidence": {"decay_law": law}, "settings": {"min_delta_bic": 10.0}, "ranking": []}
    return [ln for ln in distinguishing_lines(dg) if ln.startswith("- decay over the whole trajectory")]


def test_the_decay_law_line_names_the_law_whose_coefficient_takes_its_sign() -> None:
    from lagsplat.diagnose.reading import distinguishing_lines

    def lines(dry, drag, dry_ok=True, drag_ok=False):
        return _decay_law_lines({"dry": {"evidence": dry, "coef": 0.4, "sign_ok": dry_ok}, "drag": {"evidence": drag, "coef": -0.01, "sign_ok": drag_ok}})

    assert lines(37.1, 36.1) == ["- decay over the whole trajectory: dry friction (faster, relative to the amplitude, as it shrinks), "
                                 "evidence 37.1 over viscous damping"]  # fmt: skip
    # the drag fit's larger gain came with the wrong sign: it is dry friction's evidence, not drag's
    assert "dry friction" in lines(20.0, 25.0)[0]
    assert "no law reads it better" in lines(20.0, 25.0, dry_ok=False)[0]
    assert "no law reads it better" in lines(4.0, -3.0)[0]
    dg = {"evidence": {}, "settings": {}, "ranking": []}
    assert not [ln for ln in distinguishing_lines(dg) if "whole trajectory" in ln]  # not read: no line


def test_the_decay_law_line_gives_the_law_size_and_sets_a_negligible_one_aside() -> None:
    def line(loss):
        dry = {"evidence": 10.0, "coef": 0.02, "sign_ok": True, "loss_per_period": loss, "practical": loss >= 0.01}
        return _decay_law_lines({"dry": dry, "drag": {"evidence": 13.0, "coef": -0.01, "sign_ok": False, "loss_per_period": -0.004, "practical": False}})[0]

    assert line(0.0016) == ("- decay over the whole trajectory: dry friction reads it better than viscous damping (evidence 10.0), but it "
                            "alone takes 0.16 % of the amplitude per period, below 1 %: too small to count")  # fmt: skip
    assert line(0.043).endswith("evidence 10.0 over viscous damping; it alone takes 4.3 % of the amplitude per period")


def test_the_decay_law_line_on_one_take_names_the_damping_drift_it_cannot_tell_apart() -> None:
    def line(n_segments, law="dry"):
        rec = {"evidence": 37.0, "coef": 0.4, "sign_ok": True, "loss_per_period": 0.043, "practical": True}
        other = {"evidence": -3.0, "coef": -0.01, "sign_ok": False, "loss_per_period": -0.01, "practical": False}
        return _decay_law_lines({"n_segments": n_segments, "dry": rec if law == "dry" else other, "drag": rec if law == "drag" else other})[0]

    assert line(1).endswith("; on one take a damping that rises over the recording changes the decay alike (a take released at another "
                            "amplitude would tell them apart)")  # fmt: skip
    assert "a damping that falls over the recording" in line(1, "drag")
    assert "on one take" not in line(3)  # takes released at different amplitudes tell amplitude from time


def test_a_signature_confirmed_candidate_shows_its_own_cross_validation_and_why_it_stands() -> None:
    from lagsplat.diagnose.markdown import evidence_section
    from lagsplat.diagnose.reading import not_significant_lines

    def row(effect, cv, own, significant, support=41.0):
        return {"effect": effect, "delta_bic": 21.6, "signature_support": support, "evidence": 21.6 + support, "r2": 0.59, "cv_gain": cv,
                "cv_gain_own": own, "physical": True, "practical": True, "significant": significant, "coefficients": {}, "interpretation": {}}  # fmt: skip

    settings = {"min_delta_bic": 10.0, "min_r2": 0.1, "min_cv_gain": 0.02}
    dg = {"ranking": [row("coulomb", -0.25, 0.69, True), row("drift", 0.31, None, False, 1.6)], "settings": settings, "evidence": {}}
    text = "\n".join(evidence_section({"diagnosis": dg}))
    assert "| -0.25 (own 0.69) |" in text and "| 0.31 |" in text and "CV gain (own)" in text
    assert not any("coulomb" in ln for ln in not_significant_lines(dg))  # it stands: no rule stops it
    dg["ranking"][0].update(cv_gain_own=-0.05, significant=False)
    assert any("coulomb" in ln and "held-back blocks" in ln and "its own, with the in-class corrections held, -0.05" in ln
               for ln in not_significant_lines(dg))  # fmt: skip
