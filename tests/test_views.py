"""The views stage: cached novel views per frame, their cameras, the cache key, the sources and their errors."""

import json

import cv2
import numpy as np
import pytest

from lagsplat.io.clip import Clip, ClipError
from lagsplat.render.camera import look_at, save_cameras
from lagsplat.views import build_views, ensure_views, load_views, main_camera_of, save_views, scene_depth_range

T, M, S = 12, 3, 16


def _cams(n=M + 1, size=S):
    return [look_at((2.0 * np.sin(a), 0.0, -2.0 * np.cos(a)), (0.0, 0.0, 0.0), (0.0, -1.0, 0.0), size, size) for a in np.linspace(0, 0.8, n)]


def _clip(start=0, n=T, fps=30.0):
    rng = np.random.default_rng(0)
    meta = {"frames": [start, start + n], "original_size": [S, S], "crop": None, "resize": None}
    return Clip(images=rng.integers(0, 255, (n, S, S, 3), dtype=np.uint8), t=np.arange(n) / fps, meta=meta)


@pytest.fixture
def source(tmp_path):
    """A synthetic view source: frame i of view m is filled with the value 10 i + m."""
    n = T + 4
    images = np.zeros((n, M, S, S, 3), np.uint8) + (10 * np.arange(n)[:, None] + np.arange(M)[None]).astype(np.uint8)[:, :, None, None, None]
    np.savez(tmp_path / "v.views.npz", images=images, t=np.arange(n) / 30.0)
    save_cameras(tmp_path / "v.cameras.json", _cams())
    return {"source": "synthetic", "path": str(tmp_path / "v.views.npz"), "cameras": str(tmp_path / "v.cameras.json"), "holdout": [1]}


def test_views_line_up_with_the_clip_frames_in_time(source):
    vs = build_views(_clip(start=3), source)
    assert vs.images.shape == (T, M, S, S, 3)
    assert [int(v) for v in vs.images[:, 2, 0, 0, 0]] == [10 * (3 + i) + 2 for i in range(T)]
    assert vs.cameras[0] == _cams()[0] and len(vs.cameras) == M + 1
    assert vs.train_views == [0, 2] and vs.holdout == [1]


def test_round_trip_and_the_cache_recomputes_only_on_change(source, tmp_path):
    clip, folder = _clip(), tmp_path / "views"
    vs, computed = ensure_views(folder, clip, source)
    assert computed
    back = load_views(folder)
    assert np.array_equal(back.images, vs.images) and back.cameras == vs.cameras and back.holdout == [1] and back.key == vs.key
    cached, computed = ensure_views(folder, clip, source)
    assert not computed and cached.key == vs.key
    assert ensure_views(folder, clip, {**source, "holdout": [0]})[1]  # settings changed
    assert not ensure_views(folder, clip, {**source, "holdout": [0]})[1]
    images = np.load(source["path"])["images"]
    np.savez(source["path"], images=images[:, ::-1], t=np.arange(len(images)) / 30.0)  # the source file's bytes changed
    vs2, computed = ensure_views(folder, clip, {**source, "holdout": [0]})
    assert computed and int(vs2.images[0, 0, 0, 0, 0]) == 2
    other = _clip()
    other.images[0, 0, 0, 0] ^= 1  # the clip changed
    assert ensure_views(folder, other, {**source, "holdout": [0]})[1]


def test_bad_sources_stop_with_the_file_named(source, tmp_path):
    clip = _clip()
    with pytest.raises(ClipError, match="source must be one of"):
        build_views(clip, {**source, "source": "magic"})
    with pytest.raises(ClipError, match="nowhere.npz: views file not found"):
        build_views(clip, {**source, "path": str(tmp_path / "nowhere.npz")})
    np.savez(tmp_path / "flat.npz", images=np.zeros((T, S, S, 3), np.uint8), t=np.arange(T) / 30.0)
    with pytest.raises(ClipError, match=r"flat.npz: views must be uint8 \[T,M,H,W,3\]"):
        build_views(clip, {**source, "path": str(tmp_path / "flat.npz")})
    save_cameras(tmp_path / "two.json", _cams(2))
    with pytest.raises(ClipError, match="two.json: 2 cameras for 3 views"):
        build_views(clip, {**source, "cameras": str(tmp_path / "two.json")})
    np.savez(tmp_path / "slow.npz", images=np.zeros((T, M, S, S, 3), np.uint8), t=np.arange(T) / 20.0)
    with pytest.raises(ClipError, match="slow.npz: no view frame within"):
        build_views(clip, {**source, "path": str(tmp_path / "slow.npz")})
    with pytest.raises(ClipError, match="holdout"):
        build_views(clip, {**source, "holdout": [0, 1, 2]})
    with pytest.raises(ClipError, match="holdout"):
        build_views(clip, {**source, "holdout": [7]})


def test_sharp_names_what_is_missing(tmp_path, monkeypatch):
    monkeypatch.setenv("PATH", str(tmp_path))
    with pytest.raises(ClipError, match="'sharp' command") as e:
        build_views(_clip(), {"source": "sharp", "checkpoint": str(tmp_path / "w.pt")})
    assert "\n" not in str(e.value)
    exe = tmp_path / "sharp"
    exe.write_text("#!/bin/sh\nexit 1\n")
    exe.chmod(0o755)
    with pytest.raises(ClipError, match="needs its weights"):
        build_views(_clip(), {"source": "sharp", "checkpoint": str(tmp_path / "w.pt")})


def test_real_extra_cameras_are_read_as_videos(tmp_path):
    clip = _clip(start=2)
    paths = []
    for m in range(2):
        p = tmp_path / f"cam{m}.avi"
        w = cv2.VideoWriter(str(p), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (S, S))
        for i in range(T + 2):
            w.write(np.full((S, S, 3), 15 * i + 5 * m, np.uint8))
        w.release()
        paths.append(str(p))
    save_cameras(tmp_path / "calib.json", _cams(3))
    vs = build_views(clip, {"source": "cameras", "videos": paths, "calibration": str(tmp_path / "calib.json")})
    assert vs.images.shape == (T, 2, S, S, 3)
    assert np.abs(vs.images[:, 1, 8, 8, 0].astype(int) - (15 * (np.arange(T) + 2) + 5)).max() <= 3  # MJPG is lossy
    save_cameras(tmp_path / "big.json", _cams(3, size=2 * S))
    with pytest.raises(ClipError, match="cam0.avi: frames of 16x16 px, its calibration says 32x32"):
        build_views(clip, {"source": "cameras", "videos": paths, "calibration": str(tmp_path / "big.json")})


def test_the_main_camera_follows_the_clips_crop_and_resize():
    cam = _cams(1, size=40)[0]
    clip = _clip()
    clip.meta.update(crop=[4, 8, 36, 40], original_size=[40, 40])
    c = main_camera_of(cam, clip)  # 32x32 crop stored at 16x16
    assert (c.width, c.height) == (S, S)
    assert np.isclose(c.cx, (cam.cx - 4) / 2) and np.isclose(c.cy, (cam.cy - 8) / 2) and np.isclose(c.fx, cam.fx / 2)
    clip.meta.update(original_size=[64, 48])
    with pytest.raises(ClipError, match="64x48"):
        main_camera_of(cam, clip)


def test_scene_depth_is_where_the_camera_axes_meet():
    near, far = scene_depth_range(_cams(), spread=0.5)
    assert np.isclose(near, 1.0, atol=1e-6) and np.isclose(far, 3.0, atol=1e-6)
    with pytest.raises(ValueError):
        scene_depth_range(_cams(1))


def test_save_writes_the_index_last(source, tmp_path):
    vs = build_views(_clip(), source)
    save_views(tmp_path / "f", vs)
    info = json.loads((tmp_path / "f" / "views.json").read_text())
    assert info["key"] == vs.key and info["n_views"] == M and info["holdout"] == [1]


def test_the_cache_survives_its_index_being_deleted(source, tmp_path):
    clip, folder = _clip(), tmp_path / "views"
    ensure_views(folder, clip, source)
    (folder / "views.json").unlink()  # what a workflow manager does to a rerun job's declared output
    vs, computed = ensure_views(folder, clip, source)
    assert not computed and (folder / "views.json").is_file() and vs.holdout == [1]


def test_plane_sweep_finds_the_depth_of_a_textured_wall():
    import torch

    from lagsplat.models.decoder3d import ConditionedGaussians3D
    from lagsplat.views import plane_sweep_depth

    size = 48
    cams = [look_at((x, 0.0, -2.0), (0.0, 0.0, 0.5), (0.0, -1.0, 0.0), size, size, 50.0) for x in (0.0, -0.6, 0.6)]
    g = torch.Generator().manual_seed(0)
    side = torch.linspace(-1.5, 1.5, 31)  # 0.1 apart
    xy = torch.stack(torch.meshgrid(side, side, indexing="ij"), -1).reshape(-1, 2)
    n = len(xy)
    dec = ConditionedGaussians3D(n, 1, cams[0], depth_range=(1.0, 4.0), backend="cpu")
    with torch.no_grad():  # a wall of small random-coloured dots at world z = 0.5 (depth 2.5 from the main camera), apart
        dec.mu_raw.copy_(torch.cat([xy, torch.full((n, 1), 0.5)], 1))
        dec.L_raw.copy_(dec._raw_diagonal(torch.ones(1), 0.025, n))
        dec.mu_q.zero_()
        dec.logit_alpha.fill_(3.0)
        dec.logit_color.copy_(torch.randn(n, 3, generator=g) * 2)
        images = np.stack([(dec.render(torch.zeros(1, 1), size, size, camera=c)[0][0].permute(1, 2, 0).numpy() * 255).astype(np.uint8) for c in cams])
    depth = plane_sweep_depth(images, cams, 0, (1.2, 5.0))
    inner = depth[8:-8, 8:-8]
    assert abs(float(np.median(inner)) - 2.5) < 0.08 and np.mean(np.abs(inner - 2.5) < 0.2) > 0.8
    with pytest.raises(ValueError):
        plane_sweep_depth(images[:1], cams[:1], 0, (1.0, 2.0))
    # the static scene's depth targets: every rig camera gets the wall's depth on its textured, still pixels
    from lagsplat.views import ViewSet, static_stereo_depth

    T = 4
    frames = np.repeat(images[:1], T, 0)
    rng = np.random.default_rng(0)
    frames[:, :6, :6] = rng.integers(0, 255, (T, 6, 6, 3))  # a flickering corner: not still, never trusted
    vs = ViewSet(np.repeat(images[None, 1:], T, 0), cams, holdout=[])
    targets = static_stereo_depth(frames, vs, np.arange(T), (1.2, 5.0), n_frames=2)
    assert len(targets) == 3
    D, mask = targets[0]
    assert D.shape == mask.shape == (size, size) and not bool(mask[:6, :6].any()) and 0.2 < float(mask.float().mean()) < 0.8
    inner = D[8:-8, 8:-8][mask[8:-8, 8:-8]].numpy()
    assert abs(float(np.median(inner)) - 2.5) < 0.08


_STAND_IN = '''#!{python}
"""Stand-in for Apple's "sharp predict -i IN -o OUT -c CKPT": one PLY of SHARP's layout per image, each pixel
unprojected as a small Gaussian of its colour, at depth 3 m except the bright pixels, at 1.5 m."""
import sys
from pathlib import Path
import cv2, numpy as np
from lagsplat.views_sharp import write_sharp_ply
a = sys.argv
assert a[1] == "predict" and Path(a[a.index("-c") + 1]).is_file()
out = Path(a[a.index("-o") + 1]); out.mkdir(parents=True, exist_ok=True)
for p in sorted(Path(a[a.index("-i") + 1]).glob("*.png")):
    rgb = cv2.imread(str(p))[:, :, ::-1] / 255.0
    h, w = rgb.shape[:2]; f = 1.2 * w
    v, u = np.mgrid[0:h, 0:w] + 0.5
    z = np.where(rgb.mean(2) > 0.8, 1.5, 3.0)
    xyz = np.stack([(u - w / 2) / f * z, (v - h / 2) / f * z, z], -1).reshape(-1, 3)
    s = np.repeat((0.45 * z / f).reshape(-1, 1), 3, 1)
    q = np.tile([1.0, 0.0, 0.0, 0.0], (h * w, 1))
    write_sharp_ply(out / (p.stem + ".ply"), xyz, s, q, np.clip(rgb.reshape(-1, 3), 0.01, 0.99), np.full(h * w, 0.995), f, w, h)
'''


def test_sharp_scenes_are_rendered_into_views_around_the_main_camera(tmp_path, monkeypatch):
    """With a command that answers like ``sharp predict`` (PLY files of SHARP's layout), the views stage reads each
    frame's Gaussians, the main camera sees the frame again, and the view cameras see parallax: the near bright
    square moves across the far backdrop, which stays put at the pivot (the backdrop's depth)."""
    import sys

    import torch

    from lagsplat.render.camera import project_points
    from lagsplat.views_sharp import read_sharp_ply, render_scene, sharp_scene_in

    exe = tmp_path / "bin" / "sharp"
    exe.parent.mkdir()
    exe.write_text(_STAND_IN.format(python=sys.executable))
    exe.chmod(0o755)
    monkeypatch.setenv("PATH", f"{exe.parent}:{__import__('os').environ['PATH']}")
    (tmp_path / "w.pt").write_bytes(b"weights")
    n, S2 = 3, 32
    rng = np.random.default_rng(1)
    yy, xx = np.mgrid[0:S2, 0:S2]
    backdrop = np.stack([60 + 2 * xx, 40 + 2 * yy, 100 - xx - yy], -1)  # a smooth, textured backdrop
    frames = np.clip(backdrop[None] + rng.integers(-8, 9, (n, S2, S2, 3)), 0, 255).astype(np.uint8)
    for i in range(n):
        frames[i, 12:18, 10 + 2 * i : 16 + 2 * i] = 240  # a bright square, moving right
    clip = Clip(images=frames, t=np.arange(n) / 30.0, meta={"frames": [0, n], "original_size": [S2, S2], "crop": None, "resize": None})
    vs = build_views(clip, {"source": "sharp", "checkpoint": str(tmp_path / "w.pt"), "n_views": 4, "angle_deg": 8.0, "holdout": [2]})
    assert vs.images.shape == (n, 4, S2, S2, 3) and len(vs.cameras) == 5
    main = vs.cameras[0]
    assert main.fx == pytest.approx(1.2 * S2, rel=1e-5) and np.allclose(main.R, np.eye(3)) and np.allclose(main.t, 0.0)
    # the main camera sees the frame again (colours, scales and positions read back right)
    scene = read_sharp_ply(_ply_of(exe, tmp_path, frames[0]))
    means, covs = sharp_scene_in(scene, main)
    again = render_scene(means, covs, scene.colors, scene.opacities, main, "torch").astype(float)
    assert np.abs(again - frames[0]).mean() < 12.0
    # parallax in the first view (turned to the right): the backdrop's centre stays at the pivot, the square moves
    cam = vs.cameras[1]
    uv_far, _ = project_points(torch.tensor([0.0, 0.0, 3.0]), cam)
    uv_near, _ = project_points(torch.tensor([0.0, 0.0, 1.5]), cam)
    assert np.allclose(uv_far.numpy(), [S2 / 2, S2 / 2], atol=0.05) and abs(float(uv_near[0] - uv_far[0])) > 2.0
    bright = vs.images[1, 0].mean(2) > 200
    assert bright.sum() > 10
    xs = np.nonzero(bright)[1].mean() + 0.5
    x_main = 13.0 + 2.0  # the square's centre in frame 1
    shift_expected = float(uv_near[0] - S2 / 2)
    assert abs((xs - x_main) - shift_expected) < 1.5 and abs(xs - x_main) > 1.5


def _ply_of(exe, tmp_path, frame):
    """Run the stand-in on one frame and return its PLY path."""
    import subprocess

    d = tmp_path / "one"
    (d / "in").mkdir(parents=True)
    cv2.imwrite(str(d / "in" / "f.png"), frame[:, :, ::-1])
    subprocess.run([str(exe), "predict", "-i", str(d / "in"), "-o", str(d / "out"), "-c", str(tmp_path / "w.pt")], check=True)
    return d / "out" / "f.ply"


def test_sharp_ply_reads_sharps_conventions(tmp_path):
    """Quaternions are real part first, scales are log standard deviations, colours degree-0 harmonics of sRGB,
    opacities logits; a file without SHARP's layout is refused with its name."""
    from lagsplat.views_sharp import read_sharp_ply, write_sharp_ply

    th = np.radians(30.0)
    p = write_sharp_ply(tmp_path / "s.ply", np.array([[0.1, -0.2, 2.0]]), np.array([[0.3, 0.1, 0.05]]),
                        np.array([[np.cos(th / 2), 0.0, 0.0, np.sin(th / 2)]]), np.array([[0.2, 0.5, 0.9]]), np.array([0.7]), 50.0, 64, 48)  # fmt: skip
    sc = read_sharp_ply(p)
    Rz = np.array([[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1]])
    assert np.allclose(sc.covs[0].numpy(), Rz @ np.diag([0.09, 0.01, 0.0025]) @ Rz.T, atol=1e-6)
    assert np.allclose(sc.means[0].numpy(), [0.1, -0.2, 2.0]) and np.allclose(sc.colors[0].numpy(), [0.2, 0.5, 0.9], atol=1e-5)
    assert float(sc.opacities[0]) == pytest.approx(0.7, abs=1e-5) and (sc.focal_px, sc.width, sc.height) == (50.0, 64, 48)
    bad = tmp_path / "bad.ply"
    bad.write_text("not a ply")
    with pytest.raises(ClipError, match="bad.ply"):
        read_sharp_ply(bad)
