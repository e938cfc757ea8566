"""Tests of the ingest layer: video / image folder / npz / mcap readers, timing rule, ingest."""

from __future__ import annotations

import base64
import hashlib
import json
import struct
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest

from lagsplat.io import (
    HELD_OUT,
    TRAIN,
    Clip,
    ClipError,
    TimingWarning,
    load_clip,
    read_image_folder,
    read_mcap,
    read_npz,
    read_video,
    resolve_timing,
    sha256_file,
    zero_order_hold,
)
from lagsplat.ingest import ingest, ingest_to_file
from lagsplat.io.clip import save_clip

REAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "real"
needs_real = pytest.mark.skipif(not REAL.is_dir(), reason="real clips (../shared/data/real) not available")

SQ = 16  # side of the moving square, pixels


# --------------------------------------------------------------------------- fixtures
def _square_frame(i: int, w: int = 64, h: int = 48) -> np.ndarray:
    """RGB frame: dark background, a red square whose x position is 2*i."""
    im = np.full((h, w, 3), 20, np.uint8)
    x = 2 * i
    im[16:16 + SQ, x:x + SQ] = (230, 30, 30)
    return im


def _write_video(path: Path, n: int, fps: float, fourcc: str = "mp4v") -> Path:
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), fps, (64, 48))
    assert w.isOpened(), f"OpenCV cannot write {fourcc}"
    for i in range(n):
        w.write(cv2.cvtColor(_square_frame(i), cv2.COLOR_RGB2BGR))
    w.release()
    return path


@pytest.fixture(scope="module")
def mp4(tmp_path_factory) -> Path:
    return _write_video(tmp_path_factory.mktemp("vid") / "square.mp4", 20, 25.0)


def _sys_cfg(path: Path, **extra) -> dict:
    cfg = {"name": "test", "source": {"path": str(path)}}
    cfg.update(extra)
    return cfg


# --------------------------------------------------------------------------- timing rule
def test_timing_regular_timestamps_are_used_shifted_to_zero():
    raw = 5.0 + np.arange(10) * (1001 / 60000)
    t, info = resolve_timing(raw, "x.mov", container_fps=59.77)
    assert info["rule"] == "timestamps" and info["warnings"] == []
    np.testing.assert_allclose(t, np.arange(10) * 1001 / 60000, atol=1e-12)
    assert info["dt_ms_median"] == pytest.approx(16.6833, abs=1e-3)


def test_timing_jitter_with_plausible_container_uses_mean_rate_and_warns():
    raw = np.array([0.0, 0.031, 0.080, 0.100, 0.149, 0.180])
    with pytest.warns(TimingWarning, match="x.webm.*mean rate"):
        t, info = resolve_timing(raw, "x.webm", container_fps=30.0)
    assert info["rule"] == "mean_rate"
    np.testing.assert_allclose(t, np.arange(6) * 0.180 / 5)


def test_timing_jitter_with_absurd_container_raises_one_line():
    raw = np.cumsum([0.0, 0.031, 0.049, 0.032, 0.040, 0.033])
    with pytest.raises(ClipError) as ei:
        resolve_timing(raw, "clip.webm", container_fps=1000.0)
    msg = str(ei.value)
    assert msg.startswith("clip.webm: container claims 1000 fps and frame timestamps jitter (31-49 ms)")
    assert "system.source.fps=<Hz>" in msg and "\n" not in msg


@pytest.mark.parametrize("cfps", [0.0, -5.0, float("nan"), float("inf"), 0.5, 241.0, None])
def test_timing_absurd_container_fps_variants(cfps):
    raw = np.array([0.0, 0.0, 0.05, 0.06])  # not increasing -> jitter
    with pytest.raises(ClipError, match="jitter"):
        resolve_timing(raw, "v.mp4", container_fps=cfps)


def test_timing_config_fps_overrides_and_warns_on_mismatch():
    raw = np.arange(11) * 0.04  # 25 fps, regular
    with pytest.warns(TimingWarning, match="25 fps on average but system.source.fps=30"):
        t, info = resolve_timing(raw, "v.mp4", fps=30, container_fps=25.0)
    assert info["rule"] == "config_fps" and len(info["warnings"]) == 1
    np.testing.assert_array_equal(t, np.arange(11) / 30.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # matching fps: no warning at all
        resolve_timing(raw, "v.mp4", fps=25.2, container_fps=25.0)
    with pytest.raises(ClipError, match="positive"):
        resolve_timing(raw, "v.mp4", fps=0)


# --------------------------------------------------------------------------- video
def test_read_video_synthetic_mp4(mp4):
    frames, t, info = read_video(mp4)
    assert frames.shape == (20, 48, 64, 3) and frames.dtype == np.uint8
    assert info["rule"] == "timestamps" and info["container_fps"] == pytest.approx(25.0)
    np.testing.assert_allclose(t, np.arange(20) / 25.0, atol=1e-6)
    for i in (0, 7, 19):
        x = 2 * i
        inside = frames[i, 20:28, x + 4:x + 12].reshape(-1, 3).mean(0)
        assert inside[0] > 170 and inside[1] < 80 and inside[2] < 80  # red, so RGB order is right
        assert frames[i, 40:, :].mean() < 45  # background stays dark
    # the square moves right: the red column centroid follows 2*i
    red = frames[..., 0].astype(int) - frames[..., 2].astype(int) > 100
    cx = np.array([np.nonzero(r.any(0))[0].mean() for r in red])
    np.testing.assert_allclose(cx, 2 * np.arange(20) + (SQ - 1) / 2, atol=1.5)


def test_read_video_frame_range_and_transform(mp4):
    full, _, _ = read_video(mp4)
    frames, t, info = read_video(mp4, start=5, stop=12, transform=lambda f: f[::2, ::2].copy())
    assert frames.shape == (7, 24, 32, 3)
    np.testing.assert_array_equal(frames, full[5:12, ::2, ::2])
    np.testing.assert_allclose(t, np.arange(7) / 25.0, atol=1e-6)
    assert info["frames"] == [5, 12] and info["n_decoded"] == 20
    with pytest.raises(ClipError, match="beyond the 20 frames"):
        read_video(mp4, start=5, stop=25)


def test_read_video_config_fps_mismatch_warns(mp4):
    with pytest.warns(TimingWarning, match="square.mp4"):
        _, t, info = read_video(mp4, fps=30.0)
    np.testing.assert_array_equal(t, np.arange(20) / 30.0)
    assert info["rule"] == "config_fps" and info["warnings"]


def test_read_video_missing_and_garbage(tmp_path):
    with pytest.raises(ClipError, match=r"nope\.mp4: file not found"):
        read_video(tmp_path / "nope.mp4")
    bad = tmp_path / "garbage.mp4"
    bad.write_bytes(np.random.default_rng(0).integers(0, 256, 20000, dtype=np.uint8).tobytes())
    with pytest.raises(ClipError, match=r"garbage\.mp4: cannot decode video"):
        read_video(bad)
    empty = tmp_path / "empty.webm"
    empty.write_bytes(b"")
    with pytest.raises(ClipError, match="cannot decode video"):
        read_video(empty)


def test_read_video_truncated_avi_reports_decoded_count(tmp_path):
    src = _write_video(tmp_path / "full.avi", 40, 25.0, fourcc="MJPG")
    data = src.read_bytes()
    cut = tmp_path / "cut.avi"
    cut.write_bytes(data[: int(0.4 * len(data))])
    with pytest.raises(ClipError, match=r"cut\.avi: video is truncated or corrupt: decoded \d+ of 40 frames"):
        read_video(cut)


# --------------------------------------------------------------------------- real clips
@needs_real
def test_real_webm_needs_fps():
    with pytest.raises(ClipError) as ei:
        read_video(REAL / "oscillating_cart.webm")
    msg = str(ei.value)
    assert "oscillating_cart.webm: container claims 1000 fps and frame timestamps jitter (31-49 ms)" in msg
    assert "system.source.fps" in msg and "\n" not in msg


@needs_real
def test_real_webm_with_fps_30():
    with pytest.warns(TimingWarning, match="oscillating_cart.webm"):
        frames, t, info = read_video(REAL / "oscillating_cart.webm", fps=30, transform=lambda f: f[::8, ::8].copy())
    assert frames.shape == (242, 60, 80, 3)
    np.testing.assert_array_equal(t, np.arange(242) / 30.0)
    assert info["rule"] == "config_fps" and info["container_fps"] == 1000.0
    assert info["dt_ms_min"] == pytest.approx(31, abs=0.5) and info["dt_ms_max"] == pytest.approx(49, abs=0.5)
    assert info["width"] == 640 and info["height"] == 480


@needs_real
def test_real_mov_uses_its_uniform_timestamps():
    with warnings.catch_warnings():
        warnings.simplefilter("error", TimingWarning)
        frames, t, info = read_video(REAL / "red_apple_pendulum.mov", stop=40)
    assert info["rule"] == "timestamps" and info["n_decoded"] == 1299
    assert info["container_fps"] == pytest.approx(59.77, abs=0.01)
    assert info["dt_ms_median"] == pytest.approx(16.683, abs=1e-3)
    assert info["dt_ms_max"] - info["dt_ms_min"] < 1e-3
    assert np.median(np.diff(t)) == pytest.approx(0.016683, abs=1e-6)
    np.testing.assert_allclose(t, np.arange(40) * 1001 / 60000, atol=1e-9)
    assert frames.shape == (40, 360, 640, 3)


@needs_real
def test_real_truncated_and_garbage_mp4(tmp_path):
    data = (REAL / "bouncing_cart.mp4").read_bytes()
    cut = tmp_path / "bouncing_cart.mp4"
    cut.write_bytes(data[: int(0.4 * len(data))])
    with pytest.raises(ClipError) as ei:
        read_video(cut)
    msg = str(ei.value)
    assert msg.startswith(str(cut)) and ("truncated or corrupt" in msg or "cannot decode" in msg)
    junk = tmp_path / "junk.mp4"
    junk.write_bytes(bytes(range(256)) * 200)
    with pytest.raises(ClipError, match="cannot decode video"):
        read_video(junk)


@needs_real
def test_real_webm_ingest_crop_resize(tmp_path):
    cfg = _sys_cfg(REAL / "oscillating_cart.webm", crop=[0, 230, 640, 350], resize=[128, 24],
                   frames=[10, None], split={"train_fraction": 0.6})
    cfg["source"]["fps"] = 30.0
    with pytest.warns(TimingWarning):
        clip = ingest(cfg)
    assert clip.images.shape == (232, 24, 128, 3)
    np.testing.assert_allclose(clip.t, np.arange(232) / 30.0, atol=1e-12)
    assert (clip.split == TRAIN).sum() == int(0.6 * 232)
    assert clip.meta["source"]["sha256"] == "061e8ec7dbef6d0edfed241e628a2584a7417d350375ef3c23d9b2db4c68bcff"
    assert clip.meta["timing"]["rule"] == "config_fps" and clip.meta["timing"]["warnings"]


@needs_real
def test_real_bouncing_cart_system_config():
    """conf/system/bouncing_cart.yaml on the real clip: regular 30 fps container timestamps (no
    source.fps needed), the launching hand's frames dropped, the cart's whole travel inside the crop."""
    from lagsplat.cli import compose

    cfg = compose(["system=bouncing_cart", f"raw_dir={REAL}"])
    assert cfg.system.source.get("fps") is None
    with warnings.catch_warnings():
        warnings.simplefilter("error", TimingWarning)
        clip = ingest(cfg.system)
    assert clip.images.shape == (316, 30, 104, 3)  # frames [12, 328) of 328, crop 520x150 -> 104x30
    np.testing.assert_allclose(clip.t, np.arange(316) / 30.0, atol=1e-9)
    assert clip.meta["timing"]["rule"] == "timestamps" and clip.meta["timing"]["container_fps"] == 30.0
    assert (clip.split == TRAIN).sum() == int(0.6 * 316) == 189 and (clip.split == HELD_OUT).sum() == 127
    assert clip.meta["source"]["sha256"] == cfg.system.source.sha256
    std = clip.images.astype(np.float32).mean(-1).std(0)  # [H, W] temporal std: where the cart moves
    rows, cols = np.nonzero(std > 0.2 * std.max())
    assert rows.min() > 0 and rows.max() < 29 and cols.max() < 103  # not cut by the top, bottom or right edge


# --------------------------------------------------------------------------- image folders
def _write_png(path: Path, img: np.ndarray) -> None:
    if img.ndim == 3 and img.shape[2] == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
    elif img.ndim == 3 and img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_RGBA2BGRA)
    assert cv2.imwrite(str(path), img)


def test_image_folder_natural_order_and_timestamps(tmp_path):
    for i in range(12):  # frame0..frame11 written in shuffled order; value encodes index
        img = np.zeros((8, 10, 3), np.uint8)
        img[..., 0] = 10 * i
        img[..., 1] = 5
        _write_png(tmp_path / f"frame{i}.png", img)
    (tmp_path / "notes.txt").write_text("not an image")
    frames, t, info = read_image_folder(tmp_path, fps=10)
    assert frames.shape == (12, 8, 10, 3)
    np.testing.assert_array_equal(frames[:, 0, 0, 0], 10 * np.arange(12))  # frame2 before frame10
    np.testing.assert_array_equal(frames[:, 0, 0, 1], 5)
    np.testing.assert_allclose(t, np.arange(12) / 10)
    assert info["first_file"] == "frame0.png" and info["last_file"] == "frame11.png"
    sub, t2, _ = read_image_folder(tmp_path, fps=10, start=3, stop=6)
    np.testing.assert_array_equal(sub[:, 0, 0, 0], [30, 40, 50])
    np.testing.assert_allclose(t2, [0, 0.1, 0.2])


def test_image_folder_gray_and_alpha(tmp_path):
    _write_png(tmp_path / "a1.png", np.full((6, 7), 77, np.uint8))
    rgba = np.zeros((6, 7, 4), np.uint8)
    rgba[..., 0], rgba[..., 1], rgba[..., 2], rgba[..., 3] = 200, 100, 50, 0
    _write_png(tmp_path / "a2.png", rgba)
    cv2.imwrite(str(tmp_path / "a3.bmp"), np.full((6, 7, 3), (1, 2, 3), np.uint8))  # BGR on disk
    frames, _, _ = read_image_folder(tmp_path, fps=1)
    assert frames.shape == (3, 6, 7, 3)
    assert (frames[0] == 77).all()
    assert tuple(frames[1, 0, 0]) == (200, 100, 50)
    assert tuple(frames[2, 0, 0]) == (3, 2, 1)


def test_image_folder_errors(tmp_path):
    _write_png(tmp_path / "f1.png", np.zeros((8, 8, 3), np.uint8))
    _write_png(tmp_path / "f2.png", np.zeros((8, 8, 3), np.uint8))
    with pytest.raises(ClipError, match="image folders carry no timestamps; set system.source.fps"):
        read_image_folder(tmp_path, fps=None)
    _write_png(tmp_path / "f3.png", np.zeros((9, 8, 3), np.uint8))
    _write_png(tmp_path / "f4.png", np.zeros((10, 8, 3), np.uint8))
    with pytest.raises(ClipError) as ei:
        read_image_folder(tmp_path, fps=5)
    assert str(ei.value).startswith(str(tmp_path / "f3.png"))
    (tmp_path / "f0.jpg").write_bytes(b"not a jpeg")
    with pytest.raises(ClipError, match=r"f0\.jpg: cannot decode image"):
        read_image_folder(tmp_path, fps=5)
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(ClipError, match="no image files"):
        read_image_folder(empty, fps=5)


# --------------------------------------------------------------------------- npz
def _krauss_npz(path: Path, T: int = 30, H: int = 12, W: int = 10, **overrides) -> tuple[np.ndarray, dict]:
    rng = np.random.default_rng(1)
    u8 = rng.integers(0, 256, (T, H, W, 3), dtype=np.uint8)
    arrays = {
        "images": (u8.transpose(0, 3, 1, 2).astype(np.float32) / 255.0),
        **{f"p{k}": rng.normal(size=T).astype(np.float32) for k in (1, 2, 3, 4)},
    }
    arrays.update(overrides)
    arrays = {k: v for k, v in arrays.items() if v is not None}
    np.savez(path, **arrays)
    return u8, arrays


def test_npz_krauss_layout(tmp_path):
    p = tmp_path / "krauss.npz"
    u8, arrays = _krauss_npz(p, p10=np.arange(30, dtype=np.float64), pixels=np.zeros((3, 3)))
    frames, t, u, names, info = read_npz(p, fps=60000 / 1001)
    np.testing.assert_array_equal(frames, u8)  # round(255 * x) recovers the bytes
    assert names == ["p1", "p2", "p3", "p4", "p10"]  # natural order; 2-D 'pixels' ignored
    assert info["ignored_keys"] == ["pixels"]
    assert u.dtype == np.float32 and u.shape == (30, 5)
    np.testing.assert_array_equal(u[:, 1], arrays["p2"])
    np.testing.assert_allclose(np.diff(t), 1001 / 60000)
    _, _, u2, names2, _ = read_npz(p, dt=0.02, actuation_keys=["p3"])
    assert names2 == ["p3"] and u2.shape == (30, 1)
    fr3, t3, u3, _, _ = read_npz(p, dt=0.02, start=10, stop=20, transform=lambda f: f[2:6, 1:5].copy())
    np.testing.assert_array_equal(fr3, u8[10:20, 2:6, 1:5])
    np.testing.assert_array_equal(u3[:, 0], arrays["p1"][10:20])
    assert t3[0] == 0.0


def test_npz_other_layouts_and_t_key(tmp_path):
    gray = np.arange(4 * 5 * 6, dtype=np.uint8).reshape(4, 5, 6)
    np.savez(tmp_path / "g.npz", images=gray, t=np.array([1.0, 1.5, 2.1, 2.5]))
    frames, t, u, names, info = read_npz(tmp_path / "g.npz")
    assert frames.shape == (4, 5, 6, 3) and (frames[..., 2] == gray).all()
    np.testing.assert_allclose(t, [0.0, 0.5, 1.1, 1.5])
    assert info["rule"] == "file_t" and u.shape == (4, 0) and names == []
    hwc = np.random.default_rng(2).random((3, 4, 5, 3))
    np.savez(tmp_path / "f.npz", images=hwc)
    frames, _, _, _, _ = read_npz(tmp_path / "f.npz", fps=10)
    np.testing.assert_array_equal(frames, np.rint(hwc * 255).astype(np.uint8))
    np.savez(tmp_path / "bad.npz", images=hwc * 255)
    with pytest.raises(ClipError, match=r"must lie in \[0, 1\]"):
        read_npz(tmp_path / "bad.npz", fps=10)


def test_npz_errors(tmp_path):
    np.savez(tmp_path / "noimg.npz", frames=np.zeros((2, 3, 3)), p1=np.zeros(2))
    with pytest.raises(ClipError, match=r"noimg\.npz: no 'images' array \(keys found: frames, p1\)"):
        read_npz(tmp_path / "noimg.npz", fps=30)
    p = tmp_path / "nan.npz"
    p2 = np.zeros(30)
    p2[7] = np.nan
    _krauss_npz(p, p2=p2)
    with pytest.raises(ClipError, match=r"actuation 'p2' contains NaN"):
        read_npz(p, fps=30)
    p = tmp_path / "short.npz"
    _krauss_npz(p, T=12, p3=np.zeros(10))
    with pytest.raises(ClipError) as ei:
        read_npz(p, fps=30)
    assert str(ei.value) == f"{p}: actuation 'p3' has 10 samples but 'images' has 12 frames"
    with pytest.raises(ClipError, match="no 't' key and no frame rate"):
        read_npz(p, actuation_keys=[])
    with pytest.raises(ClipError, match="no actuation key 'q9'"):
        read_npz(p, fps=30, actuation_keys=["q9"])
    good = tmp_path / "good.npz"
    _krauss_npz(good)
    cut = tmp_path / "cut.npz"
    cut.write_bytes(good.read_bytes()[:3000])
    with pytest.raises(ClipError, match=r"cut\.npz: cannot read \.npz"):
        read_npz(cut, fps=30)
    with pytest.raises(ClipError, match="file not found"):
        read_npz(tmp_path / "absent.npz", fps=30)


# --------------------------------------------------------------------------- mcap
def _png_b64(img_rgb: np.ndarray) -> str:
    ok, buf = cv2.imencode(".png", cv2.cvtColor(img_rgb, cv2.COLOR_RGB2BGR))
    assert ok
    return base64.b64encode(buf.tobytes()).decode()


def _write_mcap(path: Path, frame_ns, act: dict[str, list[tuple[int, dict]]], extra_cdr=None) -> list[np.ndarray]:
    from mcap.writer import Writer

    imgs = []
    with open(path, "wb") as fh:
        w = Writer(fh)
        w.start(profile="", library="lagsplat-test")
        sid = w.register_schema(name="foxglove.CompressedImage", encoding="jsonschema", data=b"{}")
        cam = w.register_channel(topic="/camera/compressed", message_encoding="json", schema_id=sid)
        nsid = w.register_schema(name="Numbers", encoding="jsonschema", data=b"{}")
        chans = {topic: w.register_channel(topic=topic, message_encoding="json", schema_id=nsid) for topic in act}
        for i, ns in enumerate(frame_ns):
            img = _square_frame(i, 40, 32)
            imgs.append(img)
            msg = {"timestamp": {"sec": ns // 10**9, "nsec": ns % 10**9}, "frame_id": "cam", "format": "png",
                   "data": _png_b64(img)}
            w.add_message(cam, log_time=int(ns), data=json.dumps(msg).encode(), publish_time=int(ns))
        for topic, samples in act.items():
            for ns, obj in samples:
                w.add_message(chans[topic], log_time=int(ns), data=json.dumps(obj).encode(), publish_time=int(ns))
        if extra_cdr:
            extra_cdr(w)
        w.finish()
    return imgs


MS = 10**6


def test_mcap_frames_times_and_zero_order_hold(tmp_path):
    p = tmp_path / "rec.mcap"
    frame_ns = [1_000 * MS + 40 * MS * i for i in range(8)]
    pressure = [(1_050 * MS, {"timestamp": {"sec": 1, "nsec": 0}, "p1": 1.0, "p2": -1.0}),
                (1_120 * MS, {"p1": 2.0, "p2": -2.0}),
                (1_200 * MS, {"p1": 3.0, "p2": -3.0, "label": "x", "ok": True})]
    valve = [(900 * MS, {"data": 5}), (1_170 * MS, {"data": 7})]
    other = [(1_000 * MS, {"data": 0.5})]
    imgs = _write_mcap(p, frame_ns, {"/pressure": pressure, "/valve": valve, "/other": other})
    frames, t, u, names, info = read_mcap(p, "/camera/compressed", ["/pressure", "/valve", "/other"])
    np.testing.assert_array_equal(frames, np.stack(imgs))  # PNG is lossless
    np.testing.assert_allclose(t, np.arange(8) * 0.04, atol=1e-12)
    assert info["rule"] == "timestamps" and info["image_format"] == ["png"]
    assert names == ["p1", "p2", "/valve/data", "/other/data"]
    # frames at 1000,1040,...,1280 ms; p1 samples at 1050 (1), 1120 (2), 1200 (3): before-first -> first value
    np.testing.assert_array_equal(u[:, 0], [1, 1, 1, 2, 2, 3, 3, 3])
    np.testing.assert_array_equal(u[:, 1], [-1, -1, -1, -2, -2, -3, -3, -3])
    np.testing.assert_array_equal(u[:, 2], [5, 5, 5, 5, 5, 7, 7, 7])  # 1160 < 1170 <= 1200
    assert u.dtype == np.float32
    # frame range keeps alignment with the real log times
    fr2, t2, u2, _, _ = read_mcap(p, "/camera/compressed", ["/pressure"], start=3, stop=6)
    np.testing.assert_array_equal(fr2, np.stack(imgs[3:6]))
    np.testing.assert_allclose(t2, [0, 0.04, 0.08], atol=1e-12)
    np.testing.assert_array_equal(u2[:, 0], [2, 2, 3])


def test_mcap_errors_and_fps(tmp_path):
    p = tmp_path / "rec.mcap"
    frame_ns = [0, 30 * MS, 80 * MS, 100 * MS, 150 * MS]  # jittery log times
    _write_mcap(p, frame_ns, {"/pressure": [(0, {"p1": 1.0}), (60 * MS, {"p1": float("nan")})]})
    with pytest.raises(ClipError) as ei:
        read_mcap(p, "/camera/raw")
    assert "'/camera/raw'" in str(ei.value) and "/camera/compressed, /pressure" in str(ei.value)
    with pytest.raises(ClipError, match="states no frame rate and frame timestamps jitter"):
        read_mcap(p, "/camera/compressed")
    with pytest.warns(TimingWarning) as rec:
        _, t, _, _, info = read_mcap(p, "/camera/compressed", fps=25)
    np.testing.assert_array_equal(t, np.arange(5) / 25)
    msgs = [str(r.message) for r in rec]
    assert any("jitter (20-50 ms)" in m for m in msgs) and any("26.67 fps on average" in m for m in msgs)
    assert info["warnings"] == msgs
    with pytest.raises(ClipError, match="actuation channel 'p1' contains NaN"), pytest.warns(TimingWarning):
        read_mcap(p, "/camera/compressed", ["/pressure"], fps=25)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(p.read_bytes()[:400])
    with pytest.raises(ClipError, match=r"cut\.mcap: cannot read MCAP"):
        read_mcap(cut, "/camera/compressed", fps=25)


def _cdr(parts: list[tuple[str, object]]) -> bytes:
    """Encode little-endian CDR (offsets aligned relative to the payload start)."""
    out = bytearray()

    def align(n):
        out.extend(b"\x00" * ((-len(out)) % n))

    for kind, v in parts:
        if kind in ("i", "I"):
            align(4)
            out += struct.pack("<" + kind, v)
        elif kind == "d":
            align(8)
            out += struct.pack("<d", v)
        elif kind == "str":
            b = v.encode() + b"\x00"
            align(4)
            out += struct.pack("<I", len(b)) + b
        elif kind == "bytes":
            align(4)
            out += struct.pack("<I", len(v)) + v
    return b"\x00\x01\x00\x00" + bytes(out)


def test_mcap_ros2_cdr(tmp_path):
    from mcap.writer import Writer

    p = tmp_path / "ros.mcap"
    imgs = [_square_frame(i, 40, 32) for i in range(4)]
    with open(p, "wb") as fh:
        w = Writer(fh)
        w.start(profile="ros2", library="test")
        s_img = w.register_schema(name="sensor_msgs/msg/CompressedImage", encoding="ros2msg", data=b"")
        s_f = w.register_schema(name="std_msgs/msg/Float64", encoding="ros2msg", data=b"")
        cam = w.register_channel(topic="/cam", message_encoding="cdr", schema_id=s_img)
        pr = w.register_channel(topic="/p1", message_encoding="cdr", schema_id=s_f)
        for i, img in enumerate(imgs):
            ok, buf = cv2.imencode(".png", cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
            data = _cdr([("i", 0), ("I", i), ("str", "camera_optical"), ("str", "png"), ("bytes", buf.tobytes())])
            w.add_message(cam, log_time=i * 50 * MS, data=data, publish_time=i * 50 * MS)
            w.add_message(pr, log_time=i * 50 * MS, data=_cdr([("d", 0.25 * i)]), publish_time=i * 50 * MS)
        w.finish()
    frames, t, u, names, _ = read_mcap(p, "/cam", ["/p1"])
    np.testing.assert_array_equal(frames, np.stack(imgs))
    np.testing.assert_allclose(t, [0, 0.05, 0.1, 0.15])
    assert names == ["data"]
    np.testing.assert_array_equal(u[:, 0], [0, 0.25, 0.5, 0.75])


def test_zero_order_hold():
    out = zero_order_hold(np.array([10, 20, 30]), np.array([1.0, 2.0, 3.0]), np.array([0, 10, 15, 20, 29, 30, 99]))
    np.testing.assert_array_equal(out, [1, 1, 1, 2, 2, 3, 3])


# --------------------------------------------------------------------------- ingest
def test_ingest_video_range_crop_resize_split(mp4, tmp_path):
    cfg = _sys_cfg(mp4, frames=[4, 19], crop=[8, 8, 56, 40], resize=[24, 16], split={"train_fraction": 0.6})
    clip = ingest(cfg)
    assert isinstance(clip, Clip)
    assert clip.images.shape == (15, 16, 24, 3)
    np.testing.assert_allclose(clip.t, np.arange(15) / 25, atol=1e-6)
    assert clip.t[0] == 0.0
    n_train = int(0.6 * 15)
    assert (clip.split[:n_train] == TRAIN).all() and (clip.split[n_train:] == HELD_OUT).all()
    full, _, _ = read_video(mp4)
    ref = cv2.resize(full[4][8:40, 8:56], (24, 16), interpolation=cv2.INTER_AREA)
    np.testing.assert_array_equal(clip.images[0], ref)
    m = clip.meta
    assert m["source"]["file"] == "square.mp4" and m["source"]["sha256"] == sha256_file(mp4)
    assert m["original_size"] == [64, 48] and m["size"] == [24, 16]
    assert m["frames"] == [4, 19] and m["crop"] == [8, 8, 56, 40] and m["resize"] == [24, 16]
    assert m["timing"]["rule"] == "timestamps"
    assert m["split"]["n_train"] == n_train and m["split"]["n_held_out"] == 15 - n_train
    json.dumps(m)  # provenance must be JSON


def test_ingest_to_file_roundtrip_with_omegaconf(mp4, tmp_path):
    from omegaconf import OmegaConf

    cfg = OmegaConf.create({"name": "sq", "source": {"path": "unused.mp4", "fps": 25.0},
                            "split": {"train_fraction": 0.75}})
    with pytest.raises(ClipError, match="too short: 20 frames give 15 training and 5 held-out"):
        ingest_to_file(cfg, tmp_path / "out" / "clip.npz", source_path=mp4)  # too short for the pipeline
    from lagsplat.ingest import ingest

    clip = ingest(cfg, source_path=mp4)  # the reader and the split, without the pipeline's length floor
    assert clip.n_frames == 20 and len(clip.train_idx) == 15 and len(clip.held_out_idx) == 5
    out = save_clip(tmp_path / "out" / "clip.npz", clip)
    clip = load_clip(out)
    assert clip.n_frames == 20 and len(clip.train_idx) == 15 and len(clip.held_out_idx) == 5
    assert clip.meta["system"] == "sq" and clip.meta["timing"]["rule"] == "config_fps"
    assert [p.name for p in (tmp_path / "out").iterdir()] == ["clip.npz"]


def test_ingest_errors(mp4, tmp_path):
    with pytest.raises(ClipError, match="outside the 64x48 frame"):
        ingest(_sys_cfg(mp4, crop=[0, 0, 65, 48]))
    missing = tmp_path / "data" / "none.webm"
    with pytest.raises(ClipError) as ei:
        ingest(_sys_cfg(missing))
    assert str(missing) in str(ei.value) and "file not found" in str(ei.value)
    other = tmp_path / "x.gif"
    other.write_bytes(b"GIF89a")
    with pytest.raises(ClipError, match="unsupported source type"):
        ingest(_sys_cfg(other))
    with pytest.raises(ClipError, match="train_fraction"):
        ingest(_sys_cfg(mp4, split={"train_fraction": 1.5}))
    with pytest.raises(ClipError, match="beyond the 20 frames"):
        ingest(_sys_cfg(mp4, frames=[0, 50]))
    with pytest.raises(ClipError, match="carries no actuation"):
        ingest({"name": "x", "source": {"path": str(mp4), "actuation": ["p1"]}})


def test_ingest_npz_mcap_and_images(tmp_path):
    p = tmp_path / "k.npz"
    u8, arrays = _krauss_npz(p, T=20)
    clip = ingest({"name": "k", "source": {"path": str(p), "fps": 50.0, "actuation": ["p1", "p2"]},
                   "frames": [2, 18], "split": {"train_fraction": 0.5}})
    assert clip.u_names == ["p1", "p2"] and clip.u.shape == (16, 2)
    np.testing.assert_array_equal(clip.u[:, 1], arrays["p2"][2:18])
    np.testing.assert_array_equal(clip.images, u8[2:18])
    assert len(clip.train_idx) == 8
    m = tmp_path / "r.mcap"
    _write_mcap(m, [40 * MS * i for i in range(6)], {"/pressure": [(0, {"p1": 0.5})]})
    clip = ingest({"name": "m", "source": {"path": str(m), "image_topic": "/camera/compressed",
                                           "actuation": ["/pressure"]}})
    assert clip.n_frames == 6 and clip.u_names == ["p1"] and (clip.u == 0.5).all()
    with pytest.raises(ClipError, match="image_topic"):
        ingest({"name": "m", "source": {"path": str(m)}})
    folder = tmp_path / "imgs"
    folder.mkdir()
    for i in range(5):
        _write_png(folder / f"{i}.png", np.full((4, 4, 3), i, np.uint8))
    clip = ingest({"name": "f", "source": {"path": str(folder), "fps": 10}})
    assert clip.n_frames == 5 and len(clip.train_idx) == 4  # default train fraction 0.8
    files = sorted(folder.iterdir(), key=lambda q: int(q.stem))
    expect = hashlib.sha256("".join(f"{sha256_file(f)}  {f.name}\n" for f in files).encode()).hexdigest()
    assert clip.meta["source"]["sha256"] == expect and clip.meta["source"]["format"] == "images"


def test_ingest_synth_hook_calls_make_clip(monkeypatch):
    calls = []

    def make_clip(cfg):
        calls.append(cfg)
        return Clip(images=np.zeros((3, 4, 4, 3), np.uint8), t=np.arange(3) * 0.1)

    import lagsplat.ingest

    monkeypatch.setattr(lagsplat.ingest, "make_clip", make_clip)
    cfg = {"name": "s", "source": {"synth": {"kind": "spring"}}}
    clip = ingest(cfg)
    assert calls == [cfg] and clip.n_frames == 3


def test_atomic_artifacts_follow_the_users_umask(tmp_path):
    """An artifact gets ``0o666 & ~umask`` like any file the user writes, not mkstemp's private 0600."""
    import os

    from lagsplat.io.atomic import write_json

    old = os.umask(0o022)
    try:
        assert (write_json(tmp_path / "a.json", {"x": 1}).stat().st_mode & 0o777) == 0o644
        os.umask(0o002)
        assert (write_json(tmp_path / "b.json", {"x": 1}).stat().st_mode & 0o777) == 0o664
    finally:
        os.umask(old)
    assert json.loads((tmp_path / "b.json").read_text()) == {"x": 1}


def test_a_clip_too_short_for_the_pipeline_stops_at_ingest(tmp_path):
    """A 10-frame clip used to pass ingest, Stage 1 and the chart and fail only in Stage 2 naming no file."""
    from lagsplat.ingest import MIN_SEGMENT_FRAMES, ingest_to_file

    frames = np.zeros((10, 8, 8, 3), np.uint8)
    frames[:, 2:4, :, 0] = 255
    src = tmp_path / "short.npz"
    np.savez(src, images=frames, t=np.arange(10) / 30.0)
    cfg = {"name": "short", "source": {"path": str(src)}}
    with pytest.raises(ClipError) as e:
        ingest_to_file(cfg, tmp_path / "clip.npz")
    msg = str(e.value)
    assert "short.npz" in msg and "10 frames" in msg and f"at least {MIN_SEGMENT_FRAMES}" in msg
    assert not (tmp_path / "clip.npz").exists()
    long = np.repeat(frames, 6, axis=0)  # 60 frames: 48 training, 12 held out at the default 0.8 split
    np.savez(src, images=long, t=np.arange(60) / 30.0)
    with pytest.raises(ClipError, match="12 held-out"):
        ingest_to_file(cfg, tmp_path / "clip.npz")
    cfg["split"] = {"train_fraction": 1.0}  # no held-out frames: the split, not the length, is at fault
    with pytest.raises(ClipError, match=r"short\.npz: 60 frames give no held-out frames.*lower split\.train_fraction"):
        ingest_to_file(cfg, tmp_path / "clip.npz")
    cfg["split"] = {"train_fraction": 0.6}
    assert ingest_to_file(cfg, tmp_path / "clip.npz").exists()


@needs_real
def test_a_truncated_webm_warns_naming_the_file(tmp_path):
    """A .webm cut to 900 kB used to ingest silently as half of its frames."""
    import warnings

    from lagsplat.io.video import TruncatedVideoWarning, matroska_ends_early

    full = REAL / "oscillating_cart.webm"
    cut = tmp_path / "cut.webm"
    cut.write_bytes(full.read_bytes()[:900_000])
    with pytest.warns(TruncatedVideoWarning, match=r"cut\.webm.*cut short.*\d+ frames decoded, the container states no frame count"):
        frames, _, _ = read_video(cut, fps=30.0)
    assert 100 < len(frames) < 200
    assert matroska_ends_early(full) == (False, 242)
    with warnings.catch_warnings():
        warnings.simplefilter("error", TruncatedVideoWarning)
        assert len(read_video(full, fps=30.0)[0]) == 242


def _with_matroska_duration(data: bytes, duration_ms: float) -> bytes:
    """``data`` (a WebM whose Info element has a 1-byte size and no Duration) with a Duration element added to Info.

    Browser recordings state no duration; tools that fix that up add one. OpenCV then
    reports a frame count estimated as duration x fps.
    """
    i = data.index(bytes.fromhex("1549a966"))  # Info
    size_byte = data[i + 4]
    assert size_byte & 0x80, "Info's size is not a 1-byte EBML number"
    size = size_byte & 0x7F
    body = data[i + 5 : i + 5 + size] + bytes.fromhex("4489") + bytes([0x88]) + struct.pack(">d", duration_ms)  # Duration, float64
    assert len(body) < 0x7F
    return data[: i + 4] + bytes([0x80 | len(body)]) + body + data[i + 5 + size :]


@needs_real
def test_a_frame_count_estimated_from_an_absurd_fps_is_not_trusted(tmp_path):
    """A WebM with a Duration but a 1000 fps time base: OpenCV estimates 8066 frames for its 242.

    That count used to make the whole recording "truncated or corrupt"; it is not what the
    container states, so the checks fall back to the file's structure."""
    from lagsplat.io.video import TruncatedVideoWarning

    data = _with_matroska_duration((REAL / "oscillating_cart.webm").read_bytes(), 8066.0)
    full = tmp_path / "fixed.webm"
    full.write_bytes(data)
    assert cv2.VideoCapture(str(full)).get(cv2.CAP_PROP_FRAME_COUNT) == 8066  # what OpenCV reports
    with warnings.catch_warnings():
        warnings.simplefilter("error", TruncatedVideoWarning)
        frames, _, info = read_video(full, fps=30.0)
    assert len(frames) == 242 and info["container_frame_count"] == 8066 and not info["container_frame_count_trusted"]
    cut = tmp_path / "fixed_cut.webm"
    cut.write_bytes(data[:900_000])
    with pytest.warns(TruncatedVideoWarning, match=r"fixed_cut\.webm: the file is cut short.*frames decoded, the container states 8066 frames, an estimate"):
        frames, _, _ = read_video(cut, fps=30.0)
    assert 100 < len(frames) < 200


def test_a_video_that_ends_a_few_frames_early_warns_with_both_counts(tmp_path):
    """Decoding that stops short of the container's frame count (but within 10 %) warns naming the file and both counts."""
    from lagsplat.io.video import TruncatedVideoWarning

    src = _write_video(tmp_path / "full.avi", 100, 25.0, fourcc="MJPG")
    with warnings.catch_warnings():
        warnings.simplefilter("error", TruncatedVideoWarning)
        assert len(read_video(src)[0]) == 100
    cut = tmp_path / "cut.avi"
    cut.write_bytes(src.read_bytes()[: int(0.9 * src.stat().st_size)])
    with pytest.warns(TruncatedVideoWarning, match=r"cut\.avi: decoding ended early: \d+ frames decoded of the 100 the container states") as rec:
        frames, _, info = read_video(cut)
    assert 90 <= len(frames) < 98 and info["container_frame_count"] == 100 and info["container_frame_count_trusted"]
    assert f"{len(frames)} frames decoded" in str(rec[0].message)
