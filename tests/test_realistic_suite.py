"""The realistic suite (lagsplat.synth.realistic): clips rendered by MuJoCo with the nuisances of real video.

Skipped without MuJoCo or without an offscreen GL context (EGL).
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

import lagsplat.synth.realistic.camera  # noqa: E402,F401  (sets MUJOCO_GL=egl before MuJoCo is imported)

mujoco = pytest.importorskip("mujoco")

from lagsplat.synth.realistic import clip_spec, make_clip, motion_of, outside_class_clips, realistic_suite  # noqa: E402
from lagsplat.synth.realistic.camera import render_frames  # noqa: E402
from lagsplat.timeseries import spectral_peak_frequency  # noqa: E402


def _decode(path) -> np.ndarray:
    cap = cv2.VideoCapture(str(path))
    frames = []
    while True:
        ok, f = cap.read()
        if not ok:
            break
        frames.append(cv2.cvtColor(f, cv2.COLOR_BGR2RGB))
    return np.stack(frames)


def test_the_manifest_has_over_30_clips_over_4_systems_at_two_resolutions() -> None:
    suite = realistic_suite()
    names = [e["name"] for e in suite]
    assert len(names) == len(set(names)) and sum(e["size"] == "128" for e in suite) >= 30
    assert {e["system"] for e in suite} == {"pendulum", "spring_cart", "torsion_disk", "double_pendulum"}
    assert {e["size"] for e in suite} == {"128", "640x480"}
    effects = {e["effect"] for e in suite if e["system"] == "pendulum"}
    assert {"none", "coulomb", "quadratic_drag", "end_stop", "cubic_stiffness", "periodic_force", "drift", "missing_dof"} <= effects
    with pytest.raises(KeyError, match="unknown realistic clip"):
        clip_spec("nope")


@pytest.mark.parametrize("name", ["pendulum-none-s0-128", "spring_cart-none-s1-128", "torsion_disk-none-a120-128"])
def test_the_ground_truth_oscillates_at_its_frequency(name: str) -> None:
    m = motion_of(clip_spec(name), fps=30.0, duration_s=12.0)
    f = spectral_peak_frequency(m.q[:, :1], 1 / 30.0)
    assert abs(f - m.f0_hz) / m.f0_hz < 0.03, (f, m.f0_hz)
    accel = np.abs(np.gradient(m.qdot[:, 0], 1 / 30.0)).max()
    assert np.abs(m.hidden[2:-2]).max() < 2e-3 * accel  # no effect: nothing hidden (difference error only)


def test_the_torsion_disk_turns_by_its_release_amplitude() -> None:
    for name, amp in (("torsion_disk-none-a60-128", 60), ("torsion_disk-none-a120-128", 120)):
        m = motion_of(clip_spec(name))
        assert 0.7 * math.radians(amp) < np.abs(m.q[:, 0]).max() <= math.radians(amp) * 1.001


@pytest.mark.parametrize("effect", ["coulomb", "quadratic_drag", "end_stop", "cubic_stiffness", "periodic_force", "drift"])
def test_an_effect_shows_in_the_hidden_force(effect: str) -> None:
    none = motion_of(clip_spec("pendulum-none-s0-128")).hidden[2:-2]
    m = motion_of(clip_spec(f"pendulum-{effect}-s0-128"))
    assert np.sqrt(np.mean(m.hidden[2:-2] ** 2)) > 10 * np.sqrt(np.mean(none**2))


def test_a_clip_is_deterministic_and_has_what_real_video_has(tmp_path, gl_ok) -> None:
    name = "pendulum-none-s0-128"
    a = make_clip(name, tmp_path / "a", duration_s=2.0)
    b = make_clip(name, tmp_path / "b", duration_s=2.0)
    fa, fb = _decode(a), _decode(b)
    assert fa.shape == (60, 128, 128, 3) and np.array_equal(fa, fb)
    truth = np.load(tmp_path / "a" / f"{name}.truth.npz")
    assert truth["q"].shape == (60, 1) and float(truth["f0_hz"]) > 0
    std = fa.astype(np.float32).std(0).mean(-1)
    moving = std > 12.0  # the object and its shadow
    assert 0.01 < moving.mean() < 0.25, moving.mean()
    # the backdrop is textured (not flat) where nothing moves
    still = fa[0][~moving].astype(np.float32)
    assert still.std(0).mean() > 15.0
    # the shadow: pixels that change over time far from the object's own swept area (the bob is red)
    red = (fa[..., 0].astype(int) - fa[..., 1] > 60).any(0)
    swept = cv2.dilate(red.astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool)
    assert (moving & ~swept).sum() > 20


@pytest.mark.parametrize("entry", outside_class_clips(), ids=lambda e: e["name"])
def test_motions_outside_the_model_class_are_named_in_one_line(entry, gl_ok, tmp_path) -> None:
    from lagsplat.io.clip import ClipError
    from lagsplat.prepare import prepare_video

    m = motion_of(entry, fps=30.0, duration_s=12.0)
    assert np.all(np.diff(m.q[:, 0]) >= 0) and not math.isfinite(m.f0_hz)  # no rest state to oscillate about
    mp4 = make_clip(entry["name"], tmp_path)
    why = {"rotation": "the object turns about a point", "leaves_frame": "the moving object leaves the frame"}[entry["outside_class"]]
    with pytest.raises(ClipError) as err:
        prepare_video(mp4)
    msg = str(err.value)
    assert msg.startswith(f"{mp4}: outside the model class: {why}") and "\n" not in msg


# ---- nuisance clips (lagsplat.synth.realistic.nuisance): what the clip preparation is measured on


def _nuisance(tag: str) -> list[dict]:
    from lagsplat.synth.realistic import nuisance_clips

    return [e for e in nuisance_clips() if e["nuisance"] == tag]


def test_the_nuisance_clips_are_listed_apart_from_the_suite() -> None:
    from lagsplat.synth.realistic import nuisance_clips

    entries = nuisance_clips()
    names = [e["name"] for e in entries]
    suite = {e["name"] for e in realistic_suite() + outside_class_clips()}
    assert len(names) == len(set(names)) and not suite & set(names)
    assert {e["nuisance"] for e in entries} == {"distractor", "walk_in", "sticks", "short", "long_string", "handheld", "shaky"}
    assert all(clip_spec(n)["nuisance"] for n in names)
    assert {e["system"] for e in _nuisance("distractor")} == {"pendulum", "spring_cart"}


@pytest.mark.parametrize("entry", _nuisance("sticks"), ids=lambda e: e["name"])
def test_a_sticking_clip_swings_a_few_times_then_rests_off_centre(entry) -> None:
    m = motion_of(entry, fps=30.0, duration_s=12.0)
    q, t, tr = m.q[:, 0], m.t, m.truth
    assert 0.5 * 12.0 <= tr["moving_until_s"] <= 0.65 * 12.0  # stuck for the last 35 to 50 %
    stuck = t >= tr["moving_until_s"]
    assert np.all(q[stuck] == q[-1]) and np.all(m.qdot[stuck, 0] == 0) and stuck[t >= 8.0].all()
    assert 3.0 <= tr["observed_periods"] <= 5.0
    assert abs(q[-1]) > 0.04 * np.abs(q).max()  # off-centre: held by static friction
    assert abs(tr["observed_hz"] - m.f0_hz) / m.f0_hz < 0.02
    assert abs(tr["observed_hz_spectral"] - tr["observed_hz"]) / tr["observed_hz"] < 0.03


@pytest.mark.parametrize("entry", _nuisance("short"), ids=lambda e: e["name"])
def test_a_short_clip_holds_two_and_a_half_periods(entry) -> None:
    m = motion_of(entry, fps=30.0, duration_s=entry["duration_s"])
    assert abs(len(m.t) / 30.0 * m.truth["observed_hz"] - 2.5) <= 0.2
    assert abs(m.truth["observed_hz"] - m.f0_hz) / m.f0_hz < 0.03 and m.truth["moving_until_s"] == pytest.approx(len(m.t) / 30.0)


@pytest.mark.parametrize("entry", _nuisance("long_string"), ids=lambda e: e["name"])
def test_the_long_string_bob_rises_at_twice_the_swing_frequency(entry) -> None:
    m = motion_of(entry, fps=30.0, duration_s=12.0)
    height = -np.cos(m.q[:, 0])
    f_swing, f_height = spectral_peak_frequency(m.q[:, :1], 1 / 30.0), spectral_peak_frequency(height, 1 / 30.0)
    assert abs(f_height / f_swing - 2.0) < 0.05 and abs(f_swing - m.truth["observed_hz"]) / f_swing < 0.03
    assert m.truth["bob_vertical_m"] > 0.04 and m.truth["bob_vertical_hz"] == pytest.approx(2 * m.truth["observed_hz"])


@pytest.mark.parametrize("entry", _nuisance("distractor"), ids=lambda e: e["name"])
def test_the_distractor_moves_more_than_the_object_and_touches_the_border(entry, gl_ok) -> None:
    from lagsplat.synth.realistic.nuisance import distractor_track, nuisance_scene
    from lagsplat.synth.realistic.scene import scene_xml

    m = motion_of(entry, fps=30.0, duration_s=12.0)
    track = m.extras["distractor"]
    assert np.ptp(track[:, 0]) > 0.08 and np.ptp(track[:, 1]) > math.radians(3)
    k = np.arange(0, len(m.t), 30)  # one frame a second
    xml = scene_xml(entry["system"], distance_m=2.2, **nuisance_scene(entry))
    away = distractor_track(0, np.zeros(len(k)), entry["side"], walk_in=True)  # the figure out of view

    def render(q, extra):
        return render_frames(entry["system"], q, 128, 128, xml=xml, extra_qpos=extra).astype(np.float32)

    rest = np.zeros_like(m.q[k])
    both, figure, obj, empty = render(m.q[k], track[k]), render(rest, track[k]), render(m.q[k], away), render(rest[:1], away[:1])
    mask = np.abs(figure - empty).max(-1) > 30  # the figure's pixels, per frame
    col = -1 if entry["side"] > 0 else 0
    assert mask[:, 20:-20, col].any(1).all()  # cut by the frame's border in every frame
    assert 0.04 < mask.mean() < 0.3
    change = lambda f: np.abs(f - f.mean(0)).max(-1) > 25  # noqa: E731
    assert change(figure).sum() > change(obj).sum()  # the figure's image change beats the object's
    assert change(both).sum() > change(obj).sum()


def test_a_nuisance_clip_renders_at_its_own_length_with_its_observed_frequency(tmp_path, gl_ok) -> None:
    entry = _nuisance("short")[0]
    mp4 = make_clip(entry["name"], tmp_path)
    frames = _decode(mp4)
    truth = np.load(tmp_path / f"{entry['name']}.truth.npz")
    assert frames.shape == (round(entry["duration_s"] * 30), 128, 128, 3) and truth["q"].shape == (len(frames), 1)
    assert 0.5 < float(truth["observed_hz"]) < 1.1 and float(truth["moving_until_s"]) == pytest.approx(len(frames) / 30)


def test_the_handheld_sway_is_slow_and_a_few_percent_of_the_frame() -> None:
    from lagsplat.synth.realistic.nuisance import handheld_sway

    t = np.arange(360) / 30
    s = handheld_sway(0, t, 128, 96)
    assert np.all(np.abs(s[:, 0]) < 0.04 * 128) and np.abs(s[:, 0]).max() > 0.01 * 128
    assert np.all(np.abs(s[:, 1]) < 0.04 * 96) and np.all(np.abs(s[:, 2]) < np.radians(2.0))
    assert np.abs(np.diff(s[:, :2], axis=0)).max() < 0.5  # px per frame: a sway, not a shake
    np.testing.assert_array_equal(s, handheld_sway(0, t, 128, 96))


def test_a_handheld_frame_is_the_mean_of_its_subframes_moved_by_the_sway() -> None:
    from lagsplat.synth.realistic.nuisance import HANDHELD_SUBFRAMES, handheld_frames

    entry = _nuisance("handheld")[0]
    seen = []

    def render(q):  # a bright column at the position q takes, one per sub-frame
        seen.append(len(q))
        out = np.zeros((len(q), 32, 48, 3), np.uint8)
        cols = np.clip((24 + 40 * q[:, 0]).round().astype(int), 0, 47)
        out[np.arange(len(q)), :, cols] = 255
        return out

    frames = handheld_frames(entry, 48, 32, 30.0, 2.0, render)
    assert seen == [2 * 30 * HANDHELD_SUBFRAMES] and frames.shape == (60, 32, 48, 3)
    lit = (frames[:, 16, :, 0] > 0).sum(1)
    assert lit.max() > 1  # a fast frame smears the column over several pixels


def test_a_shaky_hand_blurs_the_still_scene_by_a_varying_amount() -> None:
    """A still scene (a thin bright column that never moves) filmed hand-held stays sharp in every frame; filmed
    by a shaking hand it smears, more in some frames than in others, and its tremor is fast (2 to 6 Hz)."""
    from lagsplat.synth.realistic.nuisance import handheld_frames, handheld_tremor

    W, H = 384, 256

    def still(q):
        out = np.zeros((len(q), H, W, 3), np.uint8)
        out[:, :, W // 2] = 255
        return out

    def spread(frames):  # the column's width, px: the middle row's light over its peak
        row = frames[:, H // 2, :, 0].astype(float)
        return row.sum(1) / row.max(1)

    calm = spread(handheld_frames(_nuisance("handheld")[0], W, H, 30.0, 2.0, still))
    shaky = spread(handheld_frames(_nuisance("shaky")[0], W, H, 30.0, 2.0, still))
    assert calm.max() < 2.2  # one pixel, or two after a sub-pixel shift
    assert shaky.max() > 1.5 * calm.max() and shaky.std() > 1.8 * calm.std()
    t = np.arange(600) / 300.0
    tremor = handheld_tremor(0, t, 96, 64)
    spectrum = np.abs(np.fft.rfft(tremor[:, 0] - tremor[:, 0].mean()))
    peak_hz = np.fft.rfftfreq(len(t), 1 / 300.0)[int(np.argmax(spectrum))]
    assert 1.5 <= peak_hz <= 6.5 and np.abs(tremor[:, 0]).max() < 0.013 * 96
