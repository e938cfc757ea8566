"""Automatic clip preparation (lagsplat.prepare): region of interest, working resolution, motion checks."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from lagsplat.io.clip import ClipError
from lagsplat.prepare import MIN_OBJECT_PX, analyse_motion, image_winding, prepare_video


def _scene(T: int = 90, W: int = 320, H: int = 240, amplitude: float = 60.0, x0: float = 200.0, noise: float = 3.0, seed: int = 0) -> np.ndarray:
    """A textured static background (checkerboard + noise pattern) with a 12 px red square swinging horizontally."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:H, :W]
    bg = np.where(((xx // 20) + (yy // 20)) % 2, 170, 110).astype(np.float32)[..., None] * np.ones(3)
    bg += rng.normal(0, 10, (H, W, 1))
    frames = []
    for t in range(T):
        f = bg.copy()
        cx = x0 + amplitude * np.sin(2 * np.pi * t / 30.0)
        f[150:162, int(cx) - 6 : int(cx) + 6] = (220, 30, 30)
        f += rng.normal(0, noise, f.shape)
        frames.append(np.clip(f, 0, 255).astype(np.uint8))
    return np.stack(frames)


def _write(path, frames: np.ndarray, fps: float = 30.0) -> str:
    H, W = frames.shape[1:3]
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (W, H))
    for f in frames:
        vw.write(cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
    vw.release()
    return str(path)


def test_the_region_of_interest_holds_the_motion_and_little_else(tmp_path):
    p = prepare_video(_write(tmp_path / "swing.mp4", _scene()), fps=30.0)
    x0, y0, x1, y1 = p.crop
    assert x0 <= 200 - 60 - 6 and x1 >= 200 + 60 + 6  # the square's whole path
    assert y0 <= 150 and y1 >= 162
    assert (x1 - x0) * (y1 - y0) < 0.25 * 320 * 240  # not the whole textured frame
    assert max(p.resize) in (64, 96, 128) and p.object_px >= MIN_OBJECT_PX
    aspect_crop, aspect_resize = (x1 - x0) / (y1 - y0), p.resize[0] / p.resize[1]
    assert aspect_resize == pytest.approx(aspect_crop, rel=0.1)
    assert p.native_size == [320, 240] and p.motion_snr > 10


def test_an_explicit_crop_is_kept_and_only_the_resolution_chosen(tmp_path):
    p = prepare_video(_write(tmp_path / "swing.mp4", _scene()), fps=30.0, crop=[100, 100, 300, 200])
    assert p.crop == [100, 100, 300, 200]
    assert p.resize[0] / p.resize[1] == pytest.approx(2.0, rel=0.05)


def test_a_clip_without_motion_is_refused():
    frames = _scene(amplitude=0.0)
    with pytest.raises(ClipError, match="nothing moves"):
        analyse_motion(frames[:, ::2, ::2], "still.mp4")


def test_an_object_leaving_the_frame_is_refused():
    frames = _scene(T=120, amplitude=140.0, x0=250.0)  # the square swings out past the right border
    with pytest.raises(ClipError, match="out.mp4: outside the model class: the moving object leaves the frame"):
        analyse_motion(frames[:, ::2, ::2], "out.mp4")


def _bar(angles: np.ndarray, size: int = 96, seed: int = 0) -> np.ndarray:
    """A bar with a dot at one end turning about the centre of a noisy textured frame, one frame per angle (rad)."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:size, :size]
    bg = np.where(((xx // 12) + (yy // 12)) % 2, 160, 100).astype(np.float32)
    out = []
    for a in angles:
        img = bg.copy()
        c = size // 2
        p = (int(c + 30 * np.cos(a)), int(c + 30 * np.sin(a)))
        img = cv2.line(img, (int(c - 30 * np.cos(a)), int(c - 30 * np.sin(a))), p, 30.0, 4)
        img = cv2.circle(img, p, 5, 240.0, -1)
        img += rng.normal(0, 3.0, img.shape)
        out.append(np.repeat(np.clip(img, 0, 255).astype(np.uint8)[..., None], 3, -1))
    return np.stack(out)


def test_a_rotation_is_told_from_an_oscillation_by_how_its_image_winds():
    t = np.arange(240) / 30.0
    swing = _bar(np.radians(120) * np.cos(2 * np.pi * 0.7 * t))  # +-120 degrees: an oscillation, retracing its arc
    spin = _bar(2 * np.pi * 0.5 * t)  # four turns in one direction
    grey = lambda f: f.astype(np.float32).mean(-1) / 255.0  # noqa: E731
    changing = lambda f: grey(f).std(0) > 0.05  # noqa: E731
    net_s, tot_s = image_winding(grey(swing), changing(swing))
    net_r, tot_r = image_winding(grey(spin), changing(spin))
    assert abs(net_s) < 0.2 * tot_s and abs(net_r) > 3.5 and abs(net_r) > 0.9 * tot_r  # an arc retraced; a loop run round
    analyse_motion(swing, "swing.mp4")  # an oscillation passes
    with pytest.raises(ClipError, match=r"spin.mp4: outside the model class: the object turns about a point"):
        analyse_motion(spin, "spin.mp4")


def test_ingest_applies_auto_and_records_it(tmp_path):
    from lagsplat.ingest import ingest

    path = _write(tmp_path / "swing.mp4", _scene())
    clip = ingest({"name": "swing", "source": {"path": path, "fps": 30.0}, "crop": "auto", "resize": "auto"})
    assert clip.meta["prepare"]["crop"] == clip.meta["crop"]
    assert [clip.images.shape[2], clip.images.shape[1]] == clip.meta["resize"] == clip.meta["prepare"]["resize"]
    plain = ingest({"name": "swing", "source": {"path": path, "fps": 30.0}})  # no key: the whole frame, native size
    assert plain.images.shape[1:3] == (240, 320) and plain.meta["prepare"] is None


def test_the_motion_frequency_is_read_and_sets_the_automatic_split(tmp_path):
    from lagsplat.ingest import ingest
    from lagsplat.prepare import HELD_OUT_PERIODS, auto_train_fraction

    path = _write(tmp_path / "swing.mp4", _scene(T=300))  # 1 Hz at 30 fps, 10 periods
    p = prepare_video(path, fps=30.0)
    assert abs(p.frequency_hz - 1.0) < 0.03
    clip = ingest({"name": "swing", "source": {"path": path, "fps": 30.0}, "crop": "auto", "resize": "auto", "split": {"train_fraction": "auto"}})
    held = clip.meta["split"]["n_held_out"]
    assert HELD_OUT_PERIODS * 30 + 3 <= held <= HELD_OUT_PERIODS * 30 + 5
    assert auto_train_fraction(1000, 1.0, 30.0) == 0.8  # a long clip keeps the default split
    with pytest.raises(ClipError, match="too short for its motion"):
        auto_train_fraction(150, 1.0, 30.0, "short.mp4")
