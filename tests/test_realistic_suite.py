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


@pytest.fixture(scope="module")
def gl_ok():
    try:
        render_frames("pendulum", np.zeros((1, 1)), 32, 32)
    except RuntimeError as exc:
        pytest.skip(f"no offscreen GL: {exc}")


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
