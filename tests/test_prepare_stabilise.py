"""A hand-held camera's sway read from the still scene and taken out before the motion analysis
(lagsplat.prepare.stabilise), and carried through the ingest."""

from __future__ import annotations

import math

import cv2
import numpy as np

from lagsplat.synth.realistic.camera import write_mp4
from lagsplat.prepare.stabilise import MIN_SWAY_PX, camera_motion, stabilise, sway_px, to_native, warp_frames

FPS, T, H, W = 30.0, 150, 96, 128


def _scene(sway: bool, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A textured wall (random blocks, seeded), a dark disc swinging left-right at 0.8 Hz, and optionally the
    whole picture shifted by a slow sway (up to 4 px, 0.2 Hz) and tilted (up to 1 degree); frames and the
    sway's true shift ``[T, 2]``."""
    rng = np.random.default_rng(seed)
    wall = cv2.resize(rng.integers(60, 200, (12, 16, 3)).astype(np.uint8), (W, H), interpolation=cv2.INTER_NEAREST)
    t = np.arange(T) / FPS
    shift = np.stack([4 * np.sin(2 * math.pi * 0.2 * t), 3 * np.sin(2 * math.pi * 0.2 * math.sqrt(2) * t + 1)], 1) if sway else np.zeros((T, 2))
    tilt = np.sin(2 * math.pi * 0.15 * t) if sway else np.zeros(T)
    frames = np.empty((T, H, W, 3), np.uint8)
    for i in range(T):
        f = wall.copy()
        cv2.circle(f, (int(W / 2 + 25 * math.sin(2 * math.pi * 0.8 * t[i])), H // 2), 8, (20, 20, 30), -1)
        A = cv2.getRotationMatrix2D(((W - 1) / 2, (H - 1) / 2), float(tilt[i]), 1.0)
        A[:, 2] += shift[i]
        frames[i] = cv2.warpAffine(f, A, (W, H), borderMode=cv2.BORDER_REPLICATE)
    return frames, shift


def test_the_sway_is_read_from_the_wall_and_warped_out() -> None:
    frames, shift = _scene(sway=True)
    A = camera_motion(frames)
    assert A is not None and A.shape == (T, 2, 3)
    # frame t's picture goes back to frame 0's: the fitted shift undoes the true one (the tilt is about the centre)
    centre = np.array([(W - 1) / 2, (H - 1) / 2, 1.0])
    back = np.einsum("tij,j->ti", A, centre) - centre[:2]
    np.testing.assert_allclose(back, -(shift - shift[0]), atol=0.35)
    out, A2, note = stabilise(frames)
    assert A2 is not None and "taken out" in note
    wall = np.ones((H, W), bool)
    wall[H // 2 - 14 : H // 2 + 14, W // 2 - 40 : W // 2 + 40] = False  # away from the disc's sweep
    inner = wall[8:-8, 8:-8]
    assert out[:, 8:-8, 8:-8][:, inner].std(0).mean() < 0.25 * frames[:, 8:-8, 8:-8][:, inner].std(0).mean()


def test_a_still_camera_and_a_large_moving_part_are_read_as_they_are() -> None:
    still, _ = _scene(sway=False)
    out, A, note = stabilise(still)
    assert A is None and note is None and out is still
    assert sway_px(camera_motion(still), W, H) < MIN_SWAY_PX
    # a textured board covering most of the frame slides back and forth in front of a plain wall: the fitted
    # "sway" follows the board, and warping it back would set the wall moving, so nothing is taken out
    rng = np.random.default_rng(3)
    board = cv2.resize(rng.integers(40, 220, (10, 12, 3)).astype(np.uint8), (100, 80), interpolation=cv2.INTER_NEAREST)
    frames = np.full((T, H, W, 3), 128, np.uint8)
    for i in range(T):
        x = int(14 + 10 * math.sin(2 * math.pi * 0.7 * i / FPS))
        frames[i, 8:88, x : x + 100] = board
    frames = np.clip(frames + np.random.default_rng(1).normal(0, 2, frames.shape), 0, 255).astype(np.uint8)
    out, A, note = stabilise(frames)
    assert A is None and out is frames


def test_to_native_scales_the_shift_and_moves_it_to_the_crop() -> None:
    A = np.array([[[math.cos(0.1), -math.sin(0.1), 2.0], [math.sin(0.1), math.cos(0.1), -1.0]]])
    N = to_native(A, 3.0, (10.0, 20.0))
    p = np.array([4.0, 5.0])  # analysis px of the crop
    want = 3.0 * (A[0, :, :2] @ p + A[0, :, 2]) + np.array([10.0, 20.0])
    np.testing.assert_allclose(N[0, :, :2] @ (3.0 * p + np.array([10.0, 20.0])) + N[0, :, 2], want)
    np.testing.assert_array_equal(warp_frames(np.zeros((1, 4, 5, 3), np.uint8), A).shape, (1, 4, 5, 3))


def test_ingest_takes_the_sway_out_of_the_clip(tmp_path) -> None:
    from lagsplat.ingest import ingest

    path = write_mp4(_scene(sway=True)[0], tmp_path / "handheld.mp4", FPS)
    clip = ingest({"name": "handheld", "source": {"path": str(path), "fps": FPS}, "crop": "auto", "resize": "auto", "split": {"train_fraction": "auto"}})
    prep = clip.meta["prepare"]
    assert prep["camera"] is not None and len(prep["camera"]) == T and "taken out" in prep["note"]
    assert abs(prep["frequency_hz"] - 0.8) < 0.02
    # inside the chosen crop the clip's pixels vary about as the still scene's do, far less than the raw
    # swaying clip's read with the same crop and size (given crop and resize: no preparation, no warp)
    fixed = {"crop": prep["crop"], "resize": prep["resize"]}
    still = ingest({"name": "still", "source": {"path": str(write_mp4(_scene(sway=False)[0], tmp_path / "still.mp4", FPS)), "fps": FPS}, **fixed})
    raw = ingest({"name": "raw", "source": {"path": str(path), "fps": FPS}, **fixed})
    img, ref, unwarped = (c.images.astype(np.float32) for c in (clip, still, raw))
    assert img.shape == ref.shape == unwarped.shape
    left, before = np.abs(img.std(0) - ref.std(0)).mean(), np.abs(unwarped.std(0) - ref.std(0)).mean()
    assert left < 0.5 * before, (left, before)  # 6.3 against 18.4 grey levels (sub-pixel residual at the blocks' edges)
    # a camera known to be still: system.stabilise = false reads the frames as they are
    off = ingest({"name": "off", "source": {"path": str(path), "fps": FPS}, "crop": "auto", "resize": "auto", "stabilise": False})
    assert off.meta["prepare"]["camera"] is None


def test_a_one_frame_clip_is_left_alone() -> None:
    frames, _ = _scene(sway=True)
    out, A, note = stabilise(frames[:1])
    assert A is None and out.shape[0] == 1


def test_a_fitted_sway_that_leaves_no_oscillation_is_not_taken(tmp_path, monkeypatch) -> None:
    """Where the "sway" was fitted to the object itself (branches that fill the frame), its warp leaves no
    oscillation: here a warp that shuffles the frames in time stands for it. The frames are then read as they
    are, the disc's 0.8 Hz is found and no camera motion is recorded."""
    import lagsplat.prepare as prepare_module
    from lagsplat.prepare import prepare_video

    path = write_mp4(_scene(sway=False)[0], tmp_path / "swing.mp4", FPS)
    taken = []

    def fitted_to_the_object(small):
        taken.append(len(small))
        A = np.tile(np.eye(2, 3), (len(small), 1, 1))
        A[:, 0, 2] = np.linspace(0, 5, len(small))
        return small[np.random.default_rng(0).permutation(len(small))], A, "the camera sways up to 5.0 px of 160: taken out"

    monkeypatch.setattr(prepare_module, "take_out_sway", fitted_to_the_object)
    p = prepare_video(path, fps=FPS)
    assert taken == [T] and p.camera is None and (p.note is None or "sways" not in p.note)
    assert abs(p.frequency_hz - 0.8) < 0.02


def test_the_warp_is_kept_where_it_stills_the_typical_pixel_though_every_edge_still_flickers(monkeypatch) -> None:
    """A shaking hand blurs every edge of a cluttered room by a varying amount: after the warp nearly every pixel
    still changes (the moving share barely falls) but the typical pixel's motion falls several-fold, and the
    warp is kept; where it leaves the typical pixel as it was (a fit to a moving part), it is not."""
    import lagsplat.prepare.stabilise as stab

    frames, _ = _scene(sway=True)
    for after, kept in (((0.96, 4.0, 50.0), True), ((0.96, 12.0, 50.0), False), ((0.96, 4.0, 20.0), False)):
        stats = iter([(0.98, 10.0, 52.0), after])  # (moving share, typical, strongest) before, then after the warp
        monkeypatch.setattr(stab, "motion_stats", lambda f, s=stats: next(s))
        _, A, note = stab.stabilise(frames)
        assert (A is not None) == kept, after
        if kept:
            assert "the typical pixel's motion 10.0 -> 4.0 grey levels" in note
