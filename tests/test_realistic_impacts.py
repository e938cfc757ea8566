"""The impact clips (lagsplat.synth.realistic.impacts): oscillators bouncing off rigid stops with restitution below 1.

The law is checked on finely sampled trajectories; the clips' motions are built without rendering; one short
clip is rendered (skipped without MuJoCo or an offscreen GL context, EGL).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

import lagsplat.synth.realistic.camera  # noqa: F401  (sets MUJOCO_GL=egl before MuJoCo is imported)
from lagsplat.synth.effect_truth import MAX_EXCURSION
from lagsplat.synth.realistic import backdrop_clips, clip_spec, impact_clips, motion_of, nuisance_clips, outside_class_clips, realistic_suite
from lagsplat.synth.realistic.impact_motion import impact_trajectory, observed_frequency
from lagsplat.synth.realistic.impacts import RELEASE, impact_scene, stops_of

W0 = 2 * math.pi * 0.8
FROZEN_TEST = ["pendulum-impact-e0.9-s0-128", "spring_cart-impact2-e0.6-s0-128", "torsion_disk-impact-e0.8-s1-128", "pendulum-impact2-e0.3-s1-128"]
"""The frozen test half (impacts module docstring)."""


def _fine(stops, e, x0, v0, sine=False, zeta=0.005, fps=2000.0, seconds=4.0):
    return impact_trajectory(W0, zeta, sine, stops, e, x0, v0, np.arange(int(seconds * fps)) / fps)


def _speeds_across(run, ti: float) -> tuple[float, float]:
    """The sampled rate just before and just after the contact at ``ti``, each extrapolated from its two nearest samples."""
    t, v = run.t, run.xdot
    dt = t[1] - t[0]
    i = int(np.searchsorted(t, ti))  # first sample at or after the contact: post-impact
    before = v[i - 1] + (v[i - 1] - v[i - 2]) * (ti - t[i - 1]) / dt
    after = v[i] - (v[i + 1] - v[i]) * (t[i] - ti) / dt
    return before, after


@pytest.mark.parametrize("sine,stops,x0,v0", [(True, (-0.15,), 0.4, 0.0), (False, (0.1,), -0.3, 0.0), (False, (-0.1, 0.12), 0.0, 0.3 * W0)])
@pytest.mark.parametrize("e", [0.3, 0.7])
def test_each_impact_reverses_the_sampled_speed_and_scales_it_by_e(sine, stops, x0, v0, e) -> None:
    run = _fine(stops, e, x0, v0, sine=sine)
    assert len(run.impact_t) >= 2
    for ti, vp, vq in zip(run.impact_t, run.v_pre, run.v_post):
        before, after = _speeds_across(run, ti)
        assert before == pytest.approx(vp, rel=1e-4) and after == pytest.approx(vq, rel=1e-4, abs=1e-9)
        if abs(vq) > 0:
            assert -after / before == pytest.approx(e, abs=1e-3)


def test_the_first_contact_comes_when_the_free_swing_reaches_the_stop() -> None:
    # undamped and linear: x = A cos(w0 t) meets the stop at -sA at t = acos(-s) / w0
    run = impact_trajectory(W0, 0.0, False, (-0.4 * 0.25,), 0.6, 0.25, 0.0, np.arange(240) / 30)
    assert run.impact_t[0] == pytest.approx(math.acos(-0.4) / W0, abs=1e-8)
    assert run.v_pre[0] == pytest.approx(-W0 * 0.25 * math.sqrt(1 - 0.4**2), rel=1e-7)


@pytest.mark.parametrize("stops,x0,v0", [((-0.1,), 0.25, 0.0), ((0.12,), -0.25, 0.0), ((-0.1, 0.15), 0.0, 0.25 * W0)])
def test_the_object_never_passes_a_stop_and_meets_it_on_every_swing_while_the_contacts_last(stops, x0, v0) -> None:
    run = _fine(stops, 0.85, x0, v0, zeta=0.002, seconds=8.0)
    for s in stops:
        side = 1.0 if s > x0 else -1.0
        assert np.max(side * (run.x - s)) <= 1e-12
    assert len(run.impact_t) >= 6
    last = run.impact_t[-1]
    # no swing without a contact: at most one smooth turning point between consecutive contacts (a swing that missed
    # the stops would add two), none before the first
    between = np.histogram(run.turn_t[run.turn_t < last], bins=run.impact_t)[0]
    assert np.all(between <= 1) and not np.any(run.turn_t < run.impact_t[0])
    if len(stops) == 1:  # the far end of every swing: exactly one
        assert np.all(between == 1)
    else:  # half swings end on alternate stops while both are reached, then on the nearer one only
        alt = np.nonzero(np.diff(run.impact_stop) == 0)[0]
        n_alt = alt[0] + 1 if len(alt) else len(run.impact_stop)
        assert n_alt >= 4 and np.all(between[: n_alt - 1] == 0)
        assert np.all(run.impact_stop[n_alt:] == np.argmin(np.abs(stops)))
    # after the last contact the swings towards the stop end just short of it (within 2 % of the release amplitude)
    k = run.impact_stop[-1]
    side = 1.0 if stops[k] > x0 else -1.0
    soon = (run.t > last) & (run.t < last + 2.0)
    gap = np.min(side * (stops[k] - run.x[soon]))
    assert 0 < gap < 0.02 * 0.25, gap


def test_a_stop_the_spring_presses_against_chatters_to_rest_on_it() -> None:
    # the stop between the release and the rest position: every swing ends on it until the object rests against it
    s, A, e = 0.1, 0.25, 0.7
    run = _fine((s,), e, A, 0.0, zeta=0.004, fps=600.0, seconds=6.0)
    assert run.rest_s is not None and run.rest_s < 6.0 and len(run.impact_t) >= 10
    assert run.impact_t[-1] == run.rest_s and run.v_post[-1] == 0.0
    between = np.histogram(run.turn_t, bins=run.impact_t)[0]  # one apex per flight, none missing
    assert np.all(between == 1) and np.all(run.turn_t < run.rest_s)
    ratio = run.v_post[:-1] / run.v_pre[:-1]
    assert np.allclose(ratio, -e)
    rest = run.t >= run.rest_s
    assert rest.sum() > 100 and np.all(run.x[rest] == s) and np.all(run.xdot[rest] == 0)
    assert np.min(run.x) >= s - 1e-12
    assert np.allclose(run.hidden[rest], W0**2 * s)  # the stop's reaction holds it against the spring


def test_the_hidden_force_is_the_impulse_of_the_frame_a_contact_falls_in() -> None:
    t = np.arange(360) / 30.0
    run = impact_trajectory(W0, 0.003, False, (-0.1, 0.12), 0.8, 0.0, 0.3 * W0, t)
    dt = 1 / 30.0
    frames = np.floor(run.impact_t / dt + 0.5).astype(int)
    assert len(set(frames)) == len(frames) >= 6
    for i, vp, vq in zip(frames, run.v_pre, run.v_post):
        jump = run.xdot[i + 1] - run.xdot[i - 1] + W0**2 * run.x[i] * 2 * dt  # the rate's change less the spring's part
        assert run.hidden[i] * dt == pytest.approx(vq - vp, rel=1e-9)
        assert jump == pytest.approx(vq - vp, rel=0.03)
    others = np.setdiff1d(np.arange(len(t)), frames)
    assert np.all(run.hidden[others] == 0)


@pytest.mark.parametrize("frac", [0.2, 0.4, 0.6])
@pytest.mark.parametrize("two", [False, True])
def test_the_observed_frequency_is_above_the_free_one(frac, two) -> None:
    A = 0.25
    stops, x0, v0 = ((-frac * A, frac * A), 0.0, W0 * A) if two else ((-frac * A,), A, 0.0)
    run = impact_trajectory(W0, 0.002, False, stops, 0.8, x0, v0, np.arange(360) / 30)
    f0 = W0 / (2 * math.pi)
    f = observed_frequency(run)
    assert f > 1.03 * f0, (f, f0)
    first = observed_frequency(run, until=run.impact_t[2])  # the first swings, cut short the most
    assert first > f
    if not two:  # the cycle keeps its free half swing: at most twice as fast
        assert f < 2 * f0


def test_bad_layouts_are_refused() -> None:
    t = np.arange(10) / 30
    with pytest.raises(ValueError, match="same side"):
        impact_trajectory(W0, 0.0, False, (0.1, 0.2), 0.5, 0.0, 1.0, t)
    with pytest.raises(ValueError, match="on a stop"):
        impact_trajectory(W0, 0.0, False, (0.1,), 0.5, 0.1, 0.0, t)
    with pytest.raises(ValueError, match="0 < e < 1"):
        impact_trajectory(W0, 0.0, False, (0.1,), 1.0, 0.0, 1.0, t)


def test_the_list_has_eight_clips_split_four_and_four_with_the_test_half_frozen() -> None:
    entries = impact_clips()
    names = [e["name"] for e in entries]
    assert len(names) == 8 == len(set(names))
    others = {e["name"] for e in realistic_suite() + outside_class_clips() + nuisance_clips() + backdrop_clips()}
    assert not others & set(names) and all(clip_spec(n) == e for n, e in zip(names, entries))
    assert [e["name"] for e in entries if e["split"] == "test"] == FROZEN_TEST
    for half in ("test", "tune"):
        part = [e for e in entries if e["split"] == half]
        assert len(part) == 4 and {e["sides"] for e in part} == {1, 2} and len({e["system"] for e in part}) == 3
    assert {e["system"] for e in entries} == {"pendulum", "spring_cart", "torsion_disk"}
    es = [e["restitution"] for e in entries]
    assert all(0.3 <= x <= 0.9 for x in es) and min(es) == 0.3 and max(es) == 0.9 and len(set(es)) == 8
    for e in entries:
        assert e["effect"] == "end_stop" and e["kind"] == "impact" and e["size"] == "128" and e["sides"] == len(e["stop_frac"])
        assert all(0.2 <= abs(f) <= 0.6 for f in e["stop_frac"])
        assert e["name"] == f"{e['system']}-impact{'' if e['sides'] == 1 else '2'}-e{e['restitution']:g}-s{e['seed']}-128"
        if e["sides"] == 2:
            assert e["stop_frac"][0] < 0 < e["stop_frac"][1]


@pytest.mark.parametrize("entry", impact_clips(), ids=lambda e: e["name"])
def test_each_clips_motion_bounces_off_its_stops_faster_than_its_free_frequency(entry) -> None:
    m = motion_of(entry, 30.0, 12.0)
    tr = json.loads(json.dumps(m.truth))  # JSON-serialisable
    assert m.q.shape == (360, 1) and m.qdot.shape == (360, 1) and m.hidden.shape == (360,) and m.t[1] == pytest.approx(1 / 30)
    assert tr["effect"] == "end_stop" and tr["kind"] == "impact" and tr["sides"] == entry["sides"] and tr["restitution"] == entry["restitution"]
    assert tr["stops"] == pytest.approx(list(stops_of(entry))) and tr["f0_hz"] == m.f0_hz and 0.6 <= m.f0_hz <= 1.0
    x0 = tr["release"]["x0"]
    for s in tr["stops"]:
        assert 0.2 <= abs(s) / RELEASE[entry["system"]] <= 0.6
        side = 1.0 if s > x0 else -1.0
        assert np.max(side * (m.q[:, 0] - s)) <= 1e-12
    if entry["system"] == "pendulum":
        assert np.abs(m.q).max() <= MAX_EXCURSION["pendulum"]
    elif entry["system"] == "spring_cart":
        assert np.abs(m.q).max() <= MAX_EXCURSION["cart"]
    imp = tr["impacts"]
    assert len(imp["t_s"]) == tr["n_impacts"] >= (6 if entry["restitution"] >= 0.6 else 3)
    nonzero = np.array(imp["v_post"]) != 0
    assert np.allclose(np.array(imp["v_post"])[nonzero] / np.array(imp["v_pre"])[nonzero], -entry["restitution"])
    assert tr["rest_s"] is None  # a stop beyond the rest position: it swings on, short of the stop, after the last contact
    assert tr["f_observed_hz"] > m.f0_hz and tr["f_impacting_hz"] >= tr["f_observed_hz"]




@pytest.mark.parametrize("name", ["spring_cart-impact2-e0.6-s0-128", "torsion_disk-impact-e0.8-s1-128", "pendulum-impact-e0.9-s0-128"])
def test_the_stop_is_drawn_where_the_object_touches_it(gl_ok, name) -> None:
    from lagsplat.synth.realistic.camera import render_frames
    from lagsplat.synth.realistic.scene import scene_xml

    e = clip_spec(name)
    q = np.array([[stops_of(e)[0]]])
    with_stop = render_frames(e["system"], q, 96, 96, xml=impact_scene(e)).astype(float).mean(-1)[0]
    plain = render_frames(e["system"], q, 96, 96, xml=scene_xml(e["system"])).astype(float).mean(-1)[0]
    changed = np.abs(with_stop - plain) > 25
    assert changed.sum() >= 10  # the stop (and, for the cart, the hidden second cart) shows
    _, xs = np.nonzero(changed)
    assert xs.min() < 80 and xs.max() > 16


def test_an_impact_clip_renders_with_its_truth(gl_ok, tmp_path) -> None:
    import cv2

    from lagsplat.synth.realistic import make_clip

    name = "pendulum-impact-e0.9-s0-128"
    mp4 = make_clip(name, tmp_path, duration_s=0.6)
    cap = cv2.VideoCapture(str(mp4))
    ok, f = cap.read()
    cap.release()
    assert ok and f.shape == (128, 128, 3)
    z = np.load(tmp_path / f"{name}.truth.npz")
    assert {"t", "q", "qdot", "hidden", "f0_hz", "truth_json"} <= set(z.files) and z["q"].shape == (18, 1)
    truth = json.loads(str(z["truth_json"]))
    assert truth["effect"] == "end_stop" and truth["kind"] == "impact" and truth["split"] == "test" and truth["sides"] == 1
    assert truth["restitution"] == 0.9 and truth["f0_hz"] == pytest.approx(float(z["f0_hz"])) and "f_observed_hz" in truth


def test_the_command_line_lists_the_impact_clips(capsys) -> None:
    from lagsplat.synth.realistic.__main__ import main

    assert main(["--list-impacts"]) == 0
    assert capsys.readouterr().out.split() == [e["name"] for e in impact_clips()]
