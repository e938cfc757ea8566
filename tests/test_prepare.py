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
    from lagsplat.prepare import HELD_OUT_PERIODS, auto_split, auto_train_fraction

    path = _write(tmp_path / "swing.mp4", _scene(T=300))  # 1 Hz at 30 fps, 10 periods
    p = prepare_video(path, fps=30.0)
    assert abs(p.frequency_hz - 1.0) < 0.03
    clip = ingest({"name": "swing", "source": {"path": path, "fps": 30.0}, "crop": "auto", "resize": "auto", "split": {"train_fraction": "auto"}})
    held = clip.meta["split"]["n_held_out"]
    assert HELD_OUT_PERIODS * 30 + 3 <= held <= HELD_OUT_PERIODS * 30 + 5
    assert auto_train_fraction(1000, 1.0, 30.0) == 0.8  # a long clip keeps the default split
    # 5 periods: too short for 3 + 3 periods, identified on all its frames
    assert auto_split(150, 1.0, 30.0) == (1.0, "no held-out validation (5.0 periods)")
    with pytest.raises(ClipError, match=r"short.mp4: too short to identify: .*1.5 periods.*set `frames`"):
        auto_split(300, 1.0, 30.0, periods=1.5, src="short.mp4")  # the object moves for 1.5 periods only


# --- recordings as people film them: other motion in the frame, a crop, a motion that stops, a short take ---

W_ROOM, H_ROOM, FPS = 240, 180, 30.0


def _room(seed: int = 0) -> np.ndarray:
    """A textured, cluttered static room (float RGB ``[H, W, 3]``)."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:H_ROOM, :W_ROOM]
    bg = (120 + 25 * np.sin(xx / 7.0) * np.cos(yy / 11.0))[..., None] * np.array([1.0, 0.95, 0.85])
    bg += rng.normal(0, 8, (H_ROOM, W_ROOM, 1))
    bg[120:124] = (90, 80, 60)  # a track
    return bg


def _film(path, n_frames: int, draw, noise: float = 2.5, seed: int = 0) -> str:
    """Render ``draw(frame, t)`` over the room for ``n_frames`` frames at :data:`FPS` and write an MP4."""
    rng = np.random.default_rng(seed + 1)
    bg = _room(seed)
    frames = []
    for i in range(n_frames):
        f = bg.copy()
        draw(f, i / FPS)
        f += rng.normal(0, noise, f.shape)
        frames.append(np.clip(f, 0, 255).astype(np.uint8))
    return _write(path, np.stack(frames), FPS)


def _cart(f: np.ndarray, x: float) -> None:
    """A 16 x 10 px red cart on the track at ``x`` px."""
    f[110:120, int(round(x)) - 8 : int(round(x)) + 8] = (210, 40, 35)


def _person(f: np.ndarray, t: float, x0: float = 222.0) -> None:
    """A person seated at the right edge, cut by the border, shifting slowly and irregularly."""
    dx = 6 * np.sin(2 * np.pi * 0.11 * t) + 4 * np.sin(2 * np.pi * 0.29 * t + 1.0) + (5.0 if t > 7.0 else 0.0)
    x = int(round(x0 + dx))
    f[60:170, x : x + 40] = (40, 45, 70)  # body
    cv2.circle(f, (x + 18, 45), 13, (150, 110, 90), -1)  # head


def _walker(f: np.ndarray, t: float, t_in: float, speed: float = 40.0) -> None:
    """A passer-by walking in from the left edge at ``t_in`` s (``speed`` px/s)."""
    if t >= t_in:
        x = int(round(-30 + speed * (t - t_in)))
        f[50:175, max(0, x) : max(0, x + 30)] = (60, 90, 50)


def test_a_person_moving_at_the_edge_is_set_aside_and_the_cart_read(tmp_path):
    f_cart = 0.55  # 6.6 periods in 12 s

    def draw(f, t):
        _cart(f, 100 + 35 * np.exp(-0.05 * t) * np.cos(2 * np.pi * f_cart * t))
        _person(f, t)
        _walker(f, t, t_in=10.5)

    path = _film(tmp_path / "cart_person.mp4", 360, draw)
    p = prepare_video(path, fps=FPS, preview=tmp_path / "prepare.png")
    assert abs(p.frequency_hz / f_cart - 1) < 0.03
    x0, y0, x1, y1 = p.crop
    assert x0 <= 100 - 35 - 8 and x1 >= 100 + 35 + 8 and x1 < 222  # the cart's whole track, not the person
    assert y0 <= 110 and y1 >= 120 and y1 - y0 < 60
    assert p.dropped and any("right" in d for d in p.dropped)  # the person, named where it is
    assert "set aside" in p.summary()
    assert (tmp_path / "prepare.png").stat().st_size > 10_000
    # the same frames cut before the walker: still the cart's frequency, not the person's
    p2 = prepare_video(path, fps=FPS, stop=300)
    assert abs(p2.frequency_hz / f_cart - 1) < 0.03


def _bob(f: np.ndarray, t: float, f_hz: float, pivot=(120.0, -260.0), length: float = 400.0, amp_deg: float = 9.0) -> None:
    """A 7 px bob on a thin string from a pivot above the frame, swinging at ``f_hz``."""
    a = np.radians(amp_deg) * np.cos(2 * np.pi * f_hz * t)
    x, y = pivot[0] + length * np.sin(a), pivot[1] + length * np.cos(a)
    cv2.line(f, (int(pivot[0]), int(pivot[1])), (int(round(x)), int(round(y))), (60, 60, 60), 1)
    cv2.circle(f, (int(round(x)), int(round(y))), 7, (30, 30, 200), -1)


def test_a_user_crop_is_where_the_motion_is_read(tmp_path):
    f_cart, f_other = 0.8, 0.35

    def draw(f, t):
        _cart(f, 70 + 30 * np.cos(2 * np.pi * f_cart * t))
        cv2.circle(f, (int(round(175 + 35 * np.sin(2 * np.pi * f_other * t))), 60), 22, (240, 240, 40), -1)  # a larger, brighter swing

    path = _film(tmp_path / "two.mp4", 360, draw)
    whole = prepare_video(path, fps=FPS)
    assert abs(whole.frequency_hz / f_other - 1) < 0.05  # left alone, the stronger oscillation is taken
    crop = [20, 95, 130, 135]
    p = prepare_video(path, fps=FPS, crop=crop)
    assert p.crop == crop and p.user_crop
    assert abs(p.frequency_hz / f_cart - 1) < 0.03  # inside the crop, the cart
    assert p.resize[0] / p.resize[1] == pytest.approx(110 / 40, rel=0.1)
    with pytest.raises(ClipError, match=r"lies outside the 240x180 frame \(set `crop`"):
        prepare_video(path, fps=FPS, crop=[0, 0, 300, 100])


def _coulomb(t: np.ndarray, f_hz: float, x0: float, mu: float) -> np.ndarray:
    """A spring cart with dry friction, released at ``x0`` (px from the spring's rest): each half period is
    harmonic about ``+-mu`` (the friction's offset, px), so every turning point is ``2 mu`` closer to the rest;
    the cart sticks at the first turning point within ``mu`` of it."""
    w, half = 2 * np.pi * f_hz, 0.5 / f_hz
    turns = [x0]
    while abs(turns[-1]) > mu:
        turns.append(2 * mu * np.sign(turns[-1]) - turns[-1])
    k = np.minimum((t / half).astype(int), len(turns) - 1)
    x = np.array([turns[-1]] * len(t), float)
    for i in np.flatnonzero(k < len(turns) - 1):
        c = mu * np.sign(turns[k[i]])
        x[i] = c + (turns[k[i]] - c) * np.cos(w * (t[i] - k[i] * half))
    return x


def test_a_motion_that_comes_to_rest_is_read_while_it_moves(tmp_path):
    from lagsplat.ingest import ingest

    f_cart, t = 0.71, np.arange(360) / FPS
    x = _coulomb(t, f_cart, 40.0, 2.6)  # 4.5 periods, then stuck at -1.6 px for the last 5.7 s
    stop_s = 9 * 0.5 / f_cart
    assert np.all(x[t > stop_s] == x[-1]) and x[-1] != 0

    path = _film(tmp_path / "sticks.mp4", 360, lambda f, ti: _cart(f, 120 + x[int(round(ti * FPS))]))
    p = prepare_video(path, fps=FPS)
    assert abs(p.frequency_hz / f_cart - 1) < 0.03
    assert stop_s - 2.0 < p.moving_s[1] < stop_s + 0.7  # about when it came to rest (its last small swings read as still)
    clip = ingest({"name": "sticks", "source": {"path": path, "fps": FPS}, "crop": "auto", "resize": "auto", "split": {"train_fraction": "auto"}})
    assert clip.meta["split"]["n_held_out"] >= 3 * FPS / f_cart and "no_held_out" not in clip.meta["split"]


def test_a_short_take_of_a_bob_on_a_long_string_is_identified_without_held_out_frames(tmp_path):
    from lagsplat.ingest import check_length, ingest

    f_bob = 0.56  # 124 frames hold 2.3 periods; the bob's height runs at twice that
    path = _film(tmp_path / "bob.mp4", 124, lambda f, ti: _bob(f, ti, f_bob))
    p = prepare_video(path, fps=FPS)
    assert abs(p.frequency_hz / f_bob - 1) < 0.03
    clip = ingest({"name": "bob", "source": {"path": path, "fps": FPS}, "crop": "auto", "resize": "auto", "split": {"train_fraction": "auto"}})
    assert clip.meta["split"]["n_held_out"] == 0 and clip.meta["split"]["no_held_out"] == "no held-out validation (2.3 periods)"
    check_length(clip, "bob.mp4")  # accepted: Stage 2 reads all its frames
    short = _film(tmp_path / "bob_short.mp4", 60, lambda f, ti: _bob(f, ti, f_bob))  # 1.1 periods
    with pytest.raises(ClipError, match=r"bob_short.mp4: too short to identify: .*set `frames`"):
        ingest({"name": "bob", "source": {"path": short, "fps": FPS}, "crop": "auto", "resize": "auto", "split": {"train_fraction": "auto"}})


def test_a_refusal_names_the_setting_to_change_and_is_drawn(tmp_path):
    from lagsplat.ingest import ingest

    frames = _scene(T=120, amplitude=140.0, x0=250.0)  # the square swings out past the right border
    path = _write(tmp_path / "out.mp4", frames)
    with pytest.raises(ClipError, match=r"out.mp4: outside the model class: the moving object leaves the frame .*set `crop`.*`frames`"):
        ingest({"name": "out", "source": {"path": path, "fps": 30.0}, "crop": "auto", "resize": "auto"}, preview=tmp_path / "prepare.png")
    assert (tmp_path / "prepare.png").stat().st_size > 10_000  # what the analysis saw, drawn all the same
    with pytest.raises(ClipError, match=r"nothing moves: .*check `frames`"):
        analyse_motion(_scene(amplitude=0.0)[:, ::2, ::2], "still.mp4")
