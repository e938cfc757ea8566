"""Repeated frames of a recording converted to a higher frame rate (lagsplat.io.repeats)."""

from __future__ import annotations

import numpy as np
import pytest

from lagsplat.io.repeats import drop_repeats, repeated_frames


def _swing(n: int, seed: int = 0) -> np.ndarray:
    """``[n, 24, 32, 3]`` uint8: a bright square swinging over a noisy grey scene (2 periods)."""
    rng = np.random.default_rng(seed)
    out = np.empty((n, 24, 32, 3), np.uint8)
    for i in range(n):
        img = np.full((24, 32, 3), 90.0) + rng.normal(0, 1.0, (24, 32, 3))
        c = int(round(14 + 9 * np.sin(4 * np.pi * i / n)))
        img[10:14, c : c + 4] = 230
        out[i] = np.clip(img, 0, 255).astype(np.uint8)
    return out


def test_every_other_frame_repeated_is_found_and_dropped_at_the_captured_rate() -> None:
    captured = _swing(60)
    shown = np.repeat(captured, 2, axis=0)  # 30 fps shown at 60
    t = np.arange(len(shown)) / 60.0
    rep = repeated_frames(shown)
    assert rep.sum() == 60 and not rep[0] and rep[1::2].all()
    images, t2, (u,), info = drop_repeats(shown, t, np.arange(len(shown)))
    assert np.array_equal(images, captured) and np.array_equal(u, np.arange(0, 120, 2))
    assert info["repeats"] == 60 and info["fps"] == pytest.approx(30.0, rel=1e-6)
    assert np.allclose(np.diff(t2), np.diff(t2)[0])  # evenly spaced


def test_a_pulldown_pattern_is_evened_out() -> None:
    captured = _swing(48)
    shown = np.concatenate([np.repeat(captured[i : i + 1], 3 if i % 2 else 2, axis=0) for i in range(48)])  # 2:3 pulldown
    images, t2, _, info = drop_repeats(shown, np.arange(len(shown)) / 60.0)
    assert np.array_equal(images, captured) and info["repeats"] == len(shown) - 48
    assert np.allclose(np.diff(t2), np.diff(t2)[0]) and 1 / np.diff(t2)[0] == pytest.approx(24.0, rel=0.05)


def test_a_clip_without_repeats_and_a_motion_that_comes_to_rest_are_left_alone() -> None:
    clip = _swing(80)
    assert not repeated_frames(clip).any()
    rest = np.concatenate([clip[:40], np.repeat(clip[39:40], 40, axis=0)])  # moves, then rests: a run of still frames
    rest = np.clip(rest.astype(float) + np.random.default_rng(1).normal(0, 1.0, rest.shape), 0, 255).astype(np.uint8)
    assert not repeated_frames(rest).any()
    t = np.arange(80) / 30.0
    images, t2, _, info = drop_repeats(rest, t)
    assert images is rest and t2 is t and info == {"repeats": 0}


def test_ingest_drops_the_repeats_of_a_video_and_says_so(tmp_path) -> None:
    import cv2

    from lagsplat.ingest import ingest
    from lagsplat.io.timing import TimingWarning

    shown = np.repeat(_swing(90), 2, axis=0)
    path = tmp_path / "repeats.avi"
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 60.0, (32, 24))
    for f in shown:
        w.write(cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
    w.release()
    cfg = {"name": "repeats", "d": 1, "source": {"path": str(path), "fps": 60.0}, "crop": None, "resize": None, "split": {"train_fraction": 0.8}}
    with pytest.warns(TimingWarning, match="of 180 frames repeat the one before"):
        clip = ingest(cfg)
    # the 90 repeats, and at most a few captured frames where the square barely moves at a turning point (JPEG smooths the noise)
    assert 86 <= len(clip.t) <= 90 and clip.meta["repeats"]["repeats"] == 180 - len(clip.t)
    assert 1 / np.median(np.diff(clip.t)) == pytest.approx(30.0, rel=0.03)


def test_alternating_repeats_are_read_by_parity_through_slow_turning_points_and_a_flip() -> None:
    """Every other frame repeated, each shown frame encoded with its own noise, a dropped frame in the middle (the
    parity flips after it), and turning points where the object barely moves: the change alone finds 80 of the 119
    repeats, the parity, run by run, all of them."""
    rng = np.random.default_rng(2)
    n = 120
    captured = np.empty((n, 24, 32, 3))
    for i in range(n):
        img = np.full((24, 32, 3), 90.0) + rng.normal(0, 1.0, (24, 32, 3))
        x = 14 + 9 * np.sin(2 * np.pi * 3 * i / n)
        c0 = int(np.floor(x))
        img[10:14, c0 : c0 + 4] = 90 + 140 * (1 - (x - c0))  # sub-pixel motion: a slow object changes little
        img[10:14, c0 + 4] = 90 + 140 * (x - c0)
        captured[i] = img
    shown = np.repeat(captured, 2, axis=0) + rng.normal(0, 1.0, (2 * n, 24, 32, 3))  # each shown frame's own encoding noise
    shown = np.delete(np.clip(shown, 0, 255).astype(np.uint8), 121, axis=0)  # one shown frame lost
    rep = repeated_frames(shown)
    assert rep.sum() == len(shown) - n
    assert not rep[:121:2].any() and rep[1:121:2].all() and rep[122::2].all() and not rep[121::2].any()  # the parity flips
    images, t2, _, info = drop_repeats(shown, np.arange(len(shown)) / 60.0)
    assert len(images) == n and info["fps"] == pytest.approx(30.0, rel=0.01)
