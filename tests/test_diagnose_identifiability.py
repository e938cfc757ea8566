"""What one recording can and cannot tell (lagsplat.diagnose.identifiability, the report's identifiability section).

The trajectories are integrated directly and diagnosed at the latent level (no Stage 1), as in
test_diagnose_signatures: a hardening spring on one steady decay, a stiffness that drifts, a short and a
long viscous decay, dry friction. Each record must say whether the recording determines the quantity and,
where not, what recording would.
"""

from __future__ import annotations

import math
import re

import pytest
from test_diagnose_signatures import _diagnose, _drifting, _oscillator

from lagsplat.diagnose.identifiability import OTHER_AMPLITUDE, identifiability
from lagsplat.diagnose.markdown import identifiability_section, render_markdown
from lagsplat.diagnose.reading import CONFOUNDED, STRONG_Z, distinguishing_lines

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _records(dg: dict) -> dict[str, dict]:
    recs = identifiability(dg)
    assert all(set(r) == {"quantity", "determined", "why", "settle_by"} for r in recs)
    assert all((r["settle_by"] is None) == r["determined"] for r in recs)  # what would settle it, exactly where not determined
    return {r["quantity"]: r for r in recs}


def test_on_one_take_a_hardening_spring_reads_like_a_drifting_stiffness_and_a_second_take_would_tell() -> None:
    dg = _diagnose(_drifting(eps=0.3, zeta=(0.006, 0.006))).to_dict()
    fr = dg["evidence"]["frequency"]
    assert abs(fr["corr_amp2_time"]) >= CONFOUNDED and fr["support_time"] < dg["settings"]["min_delta_bic"] and fr["z_amp2"] >= STRONG_Z
    rec = _records(dg)
    freq = rec["frequency: amplitude vs time"]
    assert not freq["determined"]
    assert "a hardening spring" in freq["why"] and "a stiffness drifting in time would read the same" in freq["why"]
    assert f"corr(A^2, t) = {fr['corr_amp2_time']:.2f}" in freq["why"]
    assert freq["settle_by"].startswith(OTHER_AMPLITUDE)
    nat = rec["natural frequency"]
    assert nat["determined"] and "the frequency at the recorded amplitudes" in nat["why"]
    assert rec["damping level"]["determined"]  # 0.6 % damping over eight periods: its level is read
    # the report's section says it, beside (not repeating) the lines on what tells the candidates apart
    md = "\n".join(identifiability_section({"identifiability": list(rec.values()), "diagnosis": dg}))
    assert md.lstrip().startswith("## What this recording can and cannot tell") and "Read off 1 take of training frames" in md
    assert "- **frequency: amplitude vs time**: not determined." in md and f"Would settle it: {OTHER_AMPLITUDE}" in md
    told = [ln[2:] for ln in distinguishing_lines(dg)]
    assert told and not any(t in md for t in told)


def test_a_drifting_stiffness_the_timing_separates_and_two_takes_are_determined() -> None:
    dg = _diagnose(_drifting(alpha=0.25)).to_dict()
    assert dg["evidence"]["frequency"]["support_time"] >= 10
    freq = _records(dg)["frequency: amplitude vs time"]
    assert freq["determined"] and "the timing separates a drift" in freq["why"]

    def two_takes(z_time: float) -> dict:
        fr = {"n_periods": 20, "f_mean_hz": 0.7, "z_amp2": 6.0, "z_time": z_time, "relative_shift_at_max_amplitude": 0.05,
              "corr_amp2_time": -0.5, "support_time": 0.0}  # fmt: skip
        return _records({"evidence": {"frequency": fr}, "settings": {"min_delta_bic": 10.0, "n_segments": 2}})["frequency: amplitude vs time"]

    rec = two_takes(0.4)
    assert rec["determined"] and "2 takes" in rec["why"]
    rec = two_takes(2.5)  # a trend in time that is not conclusive: z grows as periods^(3/2)
    assert not rec["determined"] and "not conclusive (z = 2.5)" in rec["why"]
    assert rec["settle_by"].startswith(f"about {math.ceil((20 * (3.0 / 2.5) ** (2 / 3) - 20) / 2)} more periods")


def _form(dg: dict) -> dict:
    return _records(dg)["damping form"]


def test_few_turning_points_leave_the_decay_form_open_and_say_how_many_more_periods() -> None:
    dg = _diagnose(_oscillator(1.0, 0.0, 0.03, duration_s=3.75)[0]).to_dict()
    rec = _records(dg)
    assert not rec["damping form"]["determined"] and "leave the three decay forms within 10" in rec["damping form"]["why"]
    assert re.match(r"about \d+ more periods? \(estimate", rec["damping form"]["settle_by"])
    timing = rec["frequency: amplitude vs time"]
    assert not timing["determined"] and "too few to regress" in timing["why"] and OTHER_AMPLITUDE in timing["settle_by"]
    assert rec["natural frequency"]["determined"]  # two periods time the frequency


def test_the_periods_a_decay_form_needs_are_an_estimate_that_a_longer_recording_meets() -> None:
    """Eight seconds of a 1 % viscous decay: the forms are within the noise; the recording extended by the
    periods the record asks for tells them apart (viscous, by at least 10 over both others)."""
    short = _form(_diagnose(_oscillator(1.0, 0.0, 0.01, duration_s=8.0)[0]).to_dict())
    assert not short["determined"]
    more = int(re.match(r"about (\d+) more periods?", short["settle_by"]).group(1))
    longer = _form(_diagnose(_oscillator(1.0, 0.0, 0.01, duration_s=8.0 + more / 0.8)[0]).to_dict())
    assert longer["determined"] and longer["why"].startswith("viscous")


def test_a_long_clean_viscous_decay_determines_the_form_and_the_level() -> None:
    rec = _records(_diagnose(_oscillator(1.0, 0.0, 0.08)[0]).to_dict())
    assert rec["damping form"]["determined"] and rec["damping form"]["why"].startswith("viscous: over 18 turning points")
    lvl = rec["damping level"]
    assert lvl["determined"] and "damping ratio about 8" in lvl["why"]  # the truth: 8 %


def test_dry_friction_on_one_take_is_read_but_a_rising_damping_would_decay_alike() -> None:
    rec = _records(_diagnose(_oscillator(1.05, 0.035, 0.005)[0]).to_dict())
    assert rec["damping form"]["determined"] and rec["damping form"]["why"].startswith("dry friction: evidence")
    pair = rec["damping form: dry friction vs a damping drifting in time"]
    assert not pair["determined"] and "a viscous damping that rises over the recording" in pair["why"]
    assert pair["settle_by"].startswith(OTHER_AMPLITUDE)
    rest = rec["where the motion rests"]
    assert rest["determined"] and "off-centre, as dry friction sticks" in rest["why"]


def test_candidates_the_residual_ranks_alike_each_get_the_recording_that_separates_them() -> None:
    def row(effect: str, ev: float) -> dict:
        return {"effect": effect, "delta_bic": ev, "evidence": ev, "physical": True}

    dg = {"evidence": {}, "settings": {"min_delta_bic": 10.0}, "ranking": [row("coulomb", 30.0), row("quadratic_drag", 29.0), row("drift", 28.5), row("end_stop", 5.0)]}
    rec = _records(dg)
    drag, drift = rec["coulomb vs quadratic_drag"], rec["coulomb vs drift"]
    assert not drag["determined"] and "evidence 30.0 and 29.0" in drag["why"] and "twice this amplitude" in drag["settle_by"]
    assert drift["settle_by"].startswith(OTHER_AMPLITUDE) and "recording's clock" in drift["settle_by"]
    assert "coulomb vs end_stop" not in rec
    dg["ranking"] = [row("coulomb", 4.0), row("quadratic_drag", 3.5)]  # nothing to tell apart from noise
    assert not any(q.startswith("coulomb vs") for q in _records(dg))


def test_no_section_where_the_report_carries_none() -> None:
    """A chart that supports no diagnosis (its ``identifiability`` is ``None``) or a report without the record."""
    assert identifiability_section({"identifiability": None}) == [] and identifiability_section({}) == []
    empty = identifiability({})  # nothing read: every quantity is open, none crashes
    assert [r["quantity"] for r in empty] == ["natural frequency", "damping level", "damping form", "frequency: amplitude vs time"]
    assert not any(r["determined"] for r in empty)
    rep = {
        "title": "t", "system": "s", "verdict": "cannot_diagnose", "verdict_text": "cannot diagnose: chart-quality gate coverage",
        "residual_ranking": {"text": "nothing significant"}, "identifiability": None,
        "diagnosis": {"null": {"excess_over_noise": 1.0}, "effects": [], "ranking": [], "evidence": {}, "settings": {}},
        "where": {"notes": []}, "gap": {"unavailable": "none"}, "refit": {"done": False, "reason": "cannot diagnose"},
        "frames": {"diagnosis_split": "train", "n_diagnosis_frames": 10, "n_held_out_frames": 0, "held_out_used_for": "nothing"},
    }  # fmt: skip
    assert "What this recording can and cannot tell" not in render_markdown(rep)


def test_the_residual_force_shape_is_named_where_it_ranks_a_stiffness_law_far_from_a_drift() -> None:
    """A realistic pendulum with a hardening spring (one take): the periods cannot tell it from a drift (z = 1.5 and -0.7,
    corr -1.00), but the residual's fit puts the cubic stiffness 50 ahead; a stop its own check sets aside is not named."""
    fr = {"n_periods": 14, "f_mean_hz": 0.966, "z_amp2": 1.54, "z_time": -0.67, "relative_shift_at_max_amplitude": 0.055,
          "corr_amp2_time": -0.996, "support_time": 2.56}  # fmt: skip
    ranking = [{"effect": "cubic_stiffness", "evidence": 52.9, "physical": True, "practical": True},
               {"effect": "end_stop", "evidence": 32.5, "physical": True, "practical": False},
               {"effect": "drift", "evidence": 2.8, "physical": True, "practical": False}]  # fmt: skip
    dg = {"evidence": {"frequency": fr}, "settings": {"min_delta_bic": 10.0, "n_segments": 1}, "ranking": ranking}
    rec = _records(dg)["frequency: amplitude vs time"]
    assert not rec["determined"] and rec["why"].endswith("puts cubic_stiffness 50.1 ahead of a drift")
    ranking[0]["practical"] = False  # only the stop's and the cubic's set-aside fits are left: the periods are all there is
    assert "ahead of" not in _records(dg)["frequency: amplitude vs time"]["why"]
