"""A hand-held camera's motion, read from the static scene and taken out of the frames.

A phone held by hand sways slowly, so every pixel moves a little and the object's path carries the sway:
read as it is, a pendulum's path was dominated by a 0.1-Hz sway and its frequency read at half its value,
and a cart's tilting picture read as a rotation. Video stabilisation undoes this before anything else:
corners of the first frame (:func:`cv2.goodFeaturesToTrack`) are followed into every frame by pyramidal
Lucas-Kanade optical flow (:func:`cv2.calcOpticalFlowPyrLK`, Bouguet 2000), and a similarity transform
(shift, rotation, scale) from each frame to the first is fitted to them by RANSAC
(:func:`cv2.estimateAffinePartial2D`), so the corners on the moving object, a minority, are outliers.
Each frame is then warped into the first frame's picture. Only a camera that moves more than
:data:`MIN_SWAY_PX` is corrected, so a clip from a camera on a tripod is read as it is, and only where the
correction stills the picture (:data:`MAX_SHARE_KEPT`, :data:`MAX_TYPICAL_KEPT`) and leaves the object moving
(:data:`MIN_MOTION_KEPT`).
"""

from __future__ import annotations

import cv2
import numpy as np

from lagsplat.io.common import warp_to_reference
from lagsplat.prepare.analysis import noise_floor

__all__ = ["camera_motion", "sway_px", "warp_frames", "to_native", "motion_stats", "stabilise", "MIN_SWAY_PX", "MAX_SHARE_KEPT",
           "MAX_TYPICAL_KEPT", "MIN_MOTION_KEPT"]

MIN_SWAY_PX = 2.0
"""Largest displacement of the frame's corners (analysis px, 160 on the long side) up to which the camera is
taken as still. A smaller sway costs less than the warp's resampling: a rendered pendulum swayed by less than
this read its frequency and its held-out gap better as it was than stabilised
(docs/experiments/code_comment_history.md)."""

MAX_SHARE_KEPT = 0.9
"""The warp is kept only where it leaves at most this share of the pixels that moved before it: a camera
sway moves the whole picture and its correction stills most of it; a "sway" fitted to a large moving part
(a person, leaves) moves the rest instead."""

MAX_TYPICAL_KEPT = 0.55
"""... or where it leaves at most this share of the typical pixel's motion (the median temporal standard deviation):
in a cluttered room filmed by a shaking hand, the blur flickers on every edge, so nearly every pixel still
changes after the warp while the typical pixel's motion falls to a fraction of its value; a fit to a moving part
leaves it as it was or raises it. The threshold is the geometric mean, rounded, of the largest share that a
camera-shake clip of the nuisance set kept and the smallest that a clip with a moving part kept (the measured
shares: docs/experiments/code_comment_history.md)."""

MIN_MOTION_KEPT = 0.5
"""The warp is kept only where the strongest motion left after it (the 99.5th percentile of the pixels'
temporal standard deviation) is at least this share of the strongest before: where the fitted "sway" is the
object itself (a large textured part moving in front of a plain background), warping it back stills the
oscillation too, and the clip is read as it is."""

_MIN_INLIERS = 12


def camera_motion(frames: np.ndarray) -> np.ndarray | None:
    """Per-frame similarity transforms ``[T, 2, 3]`` (float64) from frame ``t``'s pixels to frame 0's.

    Args:
        frames: ``[T, h, w, 3]`` uint8 RGB (the analysis frames).

    Returns:
        The transforms, or ``None`` where the first frame has too few corners to track (a plain scene:
        nothing to read the camera from). A frame whose fit fails takes its predecessor's transform.
    """
    gray = [cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for f in frames]
    p0 = cv2.goodFeaturesToTrack(gray[0], maxCorners=400, qualityLevel=0.01, minDistance=4, blockSize=5)
    if p0 is None or len(p0) < _MIN_INLIERS:
        return None
    out = np.zeros((len(frames), 2, 3))
    out[:, 0, 0] = out[:, 1, 1] = 1.0
    for t in range(1, len(frames)):
        p1, ok, _ = cv2.calcOpticalFlowPyrLK(gray[0], gray[t], p0, None, winSize=(15, 15), maxLevel=3)
        good = ok.ravel() == 1
        A = None
        if good.sum() >= _MIN_INLIERS:
            A, inl = cv2.estimateAffinePartial2D(p1[good], p0[good], method=cv2.RANSAC, ransacReprojThreshold=1.0)
            if A is not None and int(inl.sum()) < _MIN_INLIERS:
                A = None
        out[t] = out[t - 1] if A is None else A
    return out


def sway_px(A: np.ndarray, width: int, height: int) -> float:
    """Largest displacement (px) of the frame's four corners under the transforms ``A [T, 2, 3]``."""
    corners = np.array([[0, 0, 1], [width - 1, 0, 1], [0, height - 1, 1], [width - 1, height - 1, 1]], float)
    moved = np.einsum("tij,kj->tki", A, corners)
    return float(np.abs(moved - corners[None, :, :2]).max())


def warp_frames(frames: np.ndarray, A: np.ndarray) -> np.ndarray:
    """``frames [T, h, w, 3]`` uint8 warped by ``A [T, 2, 3]`` into frame 0's picture
    (:func:`lagsplat.io.common.warp_to_reference`, as the ingest warps the full-resolution frames)."""
    return np.stack([warp_to_reference(f, a) for f, a in zip(frames, A)])


def to_native(A: np.ndarray, scale: float, base: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """The transforms ``A [T, 2, 3]`` of analysis px in native px of the whole frame.

    ``scale``: native px per analysis px; ``base``: the native position of the analysed region's corner (a
    user's crop). A similarity keeps its linear part; its shift scales, and the crop's offset conjugates it.
    """
    out = np.array(A, float, copy=True)
    out[:, :, 2] *= scale
    b = np.asarray(base, float)
    out[:, :, 2] += b - np.einsum("tij,j->ti", out[:, :, :2], b)
    return out


def motion_stats(frames: np.ndarray) -> tuple[float, float, float]:
    """``(moving share, typical motion, strongest motion)`` of ``frames [T, h, w, 3]`` (uint8): the share of pixels
    whose grey level's temporal standard deviation exceeds three times the sensor noise
    (:func:`lagsplat.prepare.analysis.noise_floor`), and the median and the 99.5th percentile of that deviation
    over pixels (grey levels of 255)."""
    x = frames.astype(np.float32).mean(3) / 255.0
    std = x.std(0)
    typical, top = np.percentile(std, [50.0, 99.5])
    return float((std > 3.0 * noise_floor(x)).mean()), 255.0 * float(typical), 255.0 * float(top)


def stabilise(frames: np.ndarray) -> tuple[np.ndarray, np.ndarray | None, str | None]:
    """The frames with the camera's motion taken out, where it moved (module docstring).

    Args:
        frames: ``[T, h, w, 3]`` uint8 RGB analysis frames.

    Returns:
        ``(frames, A, note)``: the warped frames, their transforms ``[T, 2, 3]`` (frame ``t`` to frame 0,
        these frames' px) and one line saying what was done; or the frames unchanged, ``None`` and ``None``
        where the camera is still, unreadable, or its fitted motion would not still the picture.
    """
    if len(frames) < 2:
        return frames, None, None
    A = camera_motion(frames)
    if A is None:
        return frames, None, None
    h, w = frames.shape[1:3]
    sway = sway_px(A, w, h)
    if sway <= MIN_SWAY_PX:
        return frames, None, None
    warped = warp_frames(frames, A)
    (before, typ_before, top_before), (after, typ_after, top_after) = motion_stats(frames), motion_stats(warped)
    stilled = after <= MAX_SHARE_KEPT * before or typ_after <= MAX_TYPICAL_KEPT * typ_before
    if not stilled or top_after < MIN_MOTION_KEPT * top_before:
        return frames, None, None
    return warped, A, (f"the camera sways up to {sway:.1f} px of {max(h, w)}: taken out (the moving share of the picture {before:.0%} -> {after:.0%}, "
                       f"the typical pixel's motion {typ_before:.1f} -> {typ_after:.1f} grey levels)")
