"""Automatic clip preparation: region of interest, working resolution and motion checks, read off the motion.

A user's video shows a small moving object in a large, mostly static scene.
Stage 1 learns whatever is cheapest under the photometric loss (paper App. C),
so the object should fill a good part of the frame, at a resolution where its
smallest part still spans a few pixels. :func:`prepare_video` reads the clip
once at low resolution and decides, from the motion itself:

* whether anything moves at all (the largest temporal standard deviation
  against the sensor-noise floor), and whether the motion is of the model's
  class: the moving object stays in the frame (its foreground shrinks at the
  image border in few frames), and it oscillates rather than turning about a
  point (:func:`image_winding`);
* the region of interest: the box around every pixel whose temporal standard
  deviation stands out of the noise (so moving shadows count), with a margin;
* the working resolution: the box's long side at 64, 96 or 128 px, the
  smallest at which the object's typical extent spans :data:`MIN_OBJECT_PX`
  pixels (never above the native resolution).

Every choice is overridden by giving ``system.crop`` or ``system.resize``
explicitly; :mod:`lagsplat.ingest` applies the result and records it in the
clip's metadata (``meta["prepare"]``), and the CLI prints it and writes it into
the resolved configuration.
"""

from __future__ import annotations

import warnings
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from scipy.ndimage import binary_dilation, binary_opening, gaussian_filter, label

from lagsplat.io.clip import ClipError
from lagsplat.io.video import read_video
from lagsplat.timeseries import spectral_peak_frequency

__all__ = ["image_winding", "Preparation", "MIN_OBJECT_PX", "LONG_SIDES", "HELD_OUT_PERIODS", "analyse_motion", "prepare_video", "auto_train_fraction"]

#: Smallest extent (px) of the moving object at the working resolution that the resolution choice aims for.
MIN_OBJECT_PX = 8.0
#: Candidate long sides (px) of the working resolution, smallest first.
LONG_SIDES = (64, 96, 128)
#: A pixel changes when its temporal standard deviation reaches this share of the largest.
CHANGE_FRACTION = 0.15
#: A changing part is kept when its summed standard deviation reaches this share of the largest part's.
KEEP_SHARE = 0.3
#: Periods of the motion the automatic split keeps for the held-out part: the evaluation's two-period
#: horizon (``evaluate.n_periods``) and one period of room for its windows.
HELD_OUT_PERIODS = 3.0
#: The automatic split's training share: at most (the default split) and at least.
TRAIN_FRACTION_MAX, TRAIN_FRACTION_MIN = 0.8, 0.5
#: A rotation (:func:`image_winding`): at least this many net turns of the moving part's image, and this
#: share of all its turning. Every oscillation of the realistic suite and the real clips stays within 0.9
#: net turns and 7 % of its turning.
ROTATION_TURNS, ROTATION_SHARE = 2.0, 0.5
#: Long side (px) of the frames the analysis reads.
ANALYSIS_PX = 160


@dataclass
class Preparation:
    """What :func:`prepare_video` chose, and why.

    Attributes:
        crop: ``[x0, y0, x1, y1]`` native pixels, or ``None`` (keep the whole frame).
        resize: ``[width, height]`` of the working frames, pixels.
        native_size: ``[W, H]`` of the source.
        moving_fraction: share of the native frame whose pixels change (the box's content).
        object_px: the object's typical extent at the working resolution, px (square root of its area).
        motion_snr: largest temporal standard deviation over the noise floor.
        leaving_fraction: share of frames in which the object shrinks at the image border.
        frequency_hz: dominant frequency of the object's path (centroid of its departure from
            the static scene; :func:`lagsplat.timeseries.spectral_peak_frequency`), Hz.
    """

    crop: list[int] | None
    resize: list[int]
    native_size: list[int]
    moving_fraction: float
    object_px: float
    motion_snr: float
    leaving_fraction: float
    frequency_hz: float = float("nan")

    def as_dict(self) -> dict[str, Any]:
        """JSON-serialisable form (``clip.meta["prepare"]``)."""
        return asdict(self)

    def summary(self) -> str:
        """One line for the log."""
        crop = "whole frame" if self.crop is None else f"crop {self.crop}"
        return (
            f"{crop} of {self.native_size[0]}x{self.native_size[1]}, resize {self.resize[0]}x{self.resize[1]} "
            f"(object about {self.object_px:.0f} px across, motion {self.motion_snr:.0f}x the noise floor, about {self.frequency_hz:.2f} Hz)"
        )


def _downscale(long_side: int):
    """A frame transform to at most ``long_side`` px on the long side (``cv2.INTER_AREA``)."""

    def transform(frame: np.ndarray) -> np.ndarray:
        h, w = frame.shape[:2]
        s = min(1.0, long_side / max(h, w))
        if s >= 1.0:
            return frame
        return cv2.resize(frame, (max(1, round(w * s)), max(1, round(h * s))), interpolation=cv2.INTER_AREA)

    return transform


def _bounds(mass: np.ndarray, share: float = 0.005) -> tuple[int, int]:
    """``[lo, hi)`` indices holding all but ``share`` of ``mass`` at each end (robust to stray changing pixels)."""
    c = np.cumsum(mass) / max(float(mass.sum()), 1e-12)
    return int(np.searchsorted(c, share)), int(np.searchsorted(c, 1.0 - share)) + 1


def _out_of_frame(touches: np.ndarray, small: np.ndarray) -> float:
    """Share of frames in which the object is (partly) out of the frame.

    A frame counts when the object's foreground is small and it touches the border, or when it is
    small within a run of small frames that begins or ends at a frame touching the border (the
    object left, and came back, there; an object at rest merges with the static scene too, but
    not at the border).
    """
    out = small & touches
    t, T = 0, len(small)
    while t < T:
        if not small[t]:
            t += 1
            continue
        end = t
        while end < T and small[end]:
            end += 1
        if (t > 0 and touches[t - 1]) or (end < T and touches[end]) or touches[t:end].any():
            out[t:end] = True
        t = end
    return float(out.mean())


def image_winding(x: np.ndarray, changing: np.ndarray) -> tuple[float, float]:
    """How the image of the moving part turns: ``(net_turns, total_turns)`` of its two leading principal components.

    The frames' changing pixels (grey ``x [T,h,w]``, mask ``changing [h,w]``) are projected on
    their first two principal components; the angle of that 2-D path about its centre is
    unwrapped (steps where the path passes near the centre, below 0.3 of its median radius, are
    left out). An oscillation retraces an arc, so its net turning stays within about a turn
    however long the clip; an object turning about a point (a wheel, a disc spinning down)
    goes round in one direction: ``|net|`` close to ``total`` and growing with the clip.
    """
    P = x[:, changing].astype(np.float64)
    if P.shape[1] < 2 or P.shape[0] < 3:
        return 0.0, 0.0
    P -= P.mean(0)
    U, S, _ = np.linalg.svd(P, full_matrices=False)
    s1, s2 = U[:, 0] * S[0], U[:, 1] * S[1]
    r = np.hypot(s1, s2)
    step = np.diff(np.unwrap(np.arctan2(s2, s1)))
    far = (r[1:] > 0.3 * np.median(r)) & (r[:-1] > 0.3 * np.median(r))
    return float(step[far].sum() / (2 * np.pi)), float(np.abs(step[far]).sum() / (2 * np.pi))


def analyse_motion(frames: np.ndarray, src: str = "<clip>") -> dict[str, Any]:
    """Motion statistics of uint8 ``[T,h,w,3]`` frames (the analysis resolution).

    Returns:
        ``{"box": (x0, y0, x1, y1) in these frames' pixels (exclusive end), "snr", "changing" [h,w] bool,
        "object_area" (median foreground pixels per frame), "leaving_fraction"}``.

    Raises:
        ClipError: naming ``src``: fewer than 8 frames, nothing moves above the noise, or a
            motion outside the model class (a dissipative Lagrangian about a rest state): the
            moving object leaves the frame in more than 5 % of the frames, or it turns about a
            point (:func:`image_winding`, :data:`ROTATION_TURNS`).
    """
    if frames.ndim != 4 or frames.shape[0] < 8:
        raise ClipError(f"{src}: automatic preparation needs at least 8 frames, got {frames.shape[0]}")
    x = frames.astype(np.float32).mean(-1) / 255.0  # [T,h,w] grey
    T, h, w = x.shape
    std = gaussian_filter(x.std(0), 1.0)
    # the sensor-noise level: the median frame-to-frame change of a pixel, read where the scene is still
    noise = float(np.percentile(np.abs(np.diff(x, axis=0)).mean(0), 25)) / np.sqrt(2.0)
    floor = max(noise, 0.5 / 255.0)
    top = float(std.max())
    snr = top / floor
    if snr < 4.0:
        raise ClipError(f"{src}: nothing moves: the largest temporal change is {255 * top:.1f} grey levels, {snr:.1f}x the noise floor (need 4x)")
    changing = binary_opening(std > max(CHANGE_FRACTION * top, 3.0 * floor), iterations=1)
    if not changing.any():
        changing = std >= 0.5 * top
    # the moving object's parts (dilated, so that a rod and its bob, or an object and its shadow, join):
    # keep the parts that carry a good share of the largest part's change; a hand or a passer-by far
    # weaker than the object, and compression flicker, drop out
    labels, n = label(binary_dilation(changing, iterations=2), structure=np.ones((3, 3)))
    mass = np.bincount(labels[changing], weights=std[changing], minlength=n + 1)
    keep = mass >= KEEP_SHARE * mass.max()
    keep[0] = False
    changing = changing & keep[labels]
    weight = np.where(changing, std, 0.0)
    (bx0, bx1), (by0, by1) = _bounds(weight.sum(0)), _bounds(weight.sum(1))
    box = (bx0, by0, bx1, by1)
    # per-frame foreground: where the frame departs from the static scene (the median) by more than the noise
    bg = np.median(x, axis=0)
    fg = np.abs(x - bg) > max(6.0 * floor, 0.25 * top)
    area = fg.sum((1, 2)).astype(float)
    med = float(np.median(area[area > 0])) if (area > 0).any() else 0.0
    border = np.zeros((h, w), bool)
    border[:2], border[-2:], border[:, :2], border[:, -2:] = True, True, True, True
    # whether the object leaves: its foreground against the departure noise of the frames from the static
    # scene (compression leaves still blocks unchanged from frame to frame, so the frame-to-frame floor
    # above can miss the sensor noise a departure carries), and its spatial extent
    dev_noise = 1.4826 * float(np.median(np.abs(x - bg)))
    fg_obj = np.abs(x - bg) > max(4.0 * dev_noise, 6.0 * floor, 0.25 * top)
    area_obj = binary_opening(fg_obj, iterations=1, structure=np.ones((1, 2, 2))).sum((1, 2)).astype(float)  # without noise specks
    med_obj = float(np.median(area_obj[area_obj > 0])) if (area_obj > 0).any() else 0.0
    touches = (fg_obj & border).sum((1, 2)) > 0  # a sliver at the border counts
    leaving = _out_of_frame(touches, area_obj < 0.3 * med_obj) if med_obj > 0 else 0.0
    if leaving > 0.05:
        raise ClipError(
            f"{src}: outside the model class: the moving object leaves the frame (it shrinks at the image border in "
            f"{100 * leaving:.0f}% of the frames, at most 5%)"
        )
    net, total = image_winding(x, changing)
    if abs(net) >= ROTATION_TURNS and abs(net) >= ROTATION_SHARE * total:
        raise ClipError(
            f"{src}: outside the model class: the object turns about a point ({abs(net):.1f} turns of its image in one direction, "
            f"{100 * abs(net) / total:.0f}% of its turning), a rotation, not an oscillation about a rest state"
        )
    # the object's path: the centroid of its departure from the static scene, on its more mobile axis
    dev = np.abs(x - bg) * changing[None]
    mass = dev.sum((1, 2))
    ys_, xs_ = np.mgrid[:h, :w]
    cx = (dev * xs_[None]).sum((1, 2)) / np.maximum(mass, 1e-9)
    cy = (dev * ys_[None]).sum((1, 2)) / np.maximum(mass, 1e-9)
    path = cx if cx.std() >= cy.std() else cy
    return {"box": box, "snr": snr, "changing": changing, "object_area": med, "leaving_fraction": leaving, "path": path}


def prepare_video(
    path: str | Path, fps: float | None = None, start: int = 0, stop: int | None = None, crop: list[int] | None = None, **timing: float
) -> Preparation:
    """Choose the region of interest and the working resolution of a video from its motion (module docstring).

    Args:
        path: the video file.
        fps, timing: as :func:`lagsplat.io.video.read_video` (``max_fps``, ``jitter_tol``).
        start, stop: the frame range ``[start, stop)`` the clip keeps.
        crop: a region of interest given by the user (``[x0, y0, x1, y1]`` native px): kept,
            and the resolution chosen for it.

    Returns:
        The :class:`Preparation`.

    Raises:
        ClipError: as :func:`analyse_motion`, naming the file.
    """
    src = str(path)
    with warnings.catch_warnings():  # the timing warnings come again when the clip is read
        warnings.simplefilter("ignore")
        small, _, info = read_video(path, fps=fps, start=start, stop=stop, transform=_downscale(ANALYSIS_PX), **timing)
    m = analyse_motion(small, src)
    h, w = small.shape[1:3]
    native = [int(info.get("width") or w), int(info.get("height") or h)]
    s = native[0] / w  # native px per analysis px
    x0, y0, x1, y1 = m["box"]
    bw, bh = x1 - x0, y1 - y0
    pad = max(2.0, 0.15 * max(bw, bh))
    x0, y0 = max(0.0, x0 - pad), max(0.0, y0 - pad)
    x1, y1 = min(float(w), x1 + pad), min(float(h), y1 + pad)
    if crop is None:
        crop = [int(np.floor(x0 * s)), int(np.floor(y0 * s)), int(np.ceil(x1 * s)), int(np.ceil(y1 * s))]
        crop = [max(0, crop[0]), max(0, crop[1]), min(native[0], crop[2]), min(native[1], crop[3])]
        if crop[2] - crop[0] >= 0.95 * native[0] and crop[3] - crop[1] >= 0.95 * native[1]:
            crop = None
    cw, ch = (native[0], native[1]) if crop is None else (crop[2] - crop[0], crop[3] - crop[1])
    extent_native = np.sqrt(max(m["object_area"], 1.0)) * s
    long_native = max(cw, ch)
    long_side = LONG_SIDES[-1]
    for L in LONG_SIDES:
        if extent_native * L / long_native >= MIN_OBJECT_PX:
            long_side = L
            break
    long_side = min(long_side, long_native)
    k = long_side / long_native
    resize = [max(8, int(round(cw * k))), max(8, int(round(ch * k)))]
    return Preparation(
        crop=crop,
        resize=resize,
        native_size=native,
        moving_fraction=float(m["changing"].mean()),
        object_px=float(extent_native * k),
        motion_snr=float(m["snr"]),
        leaving_fraction=float(m["leaving_fraction"]),
        frequency_hz=spectral_peak_frequency(m["path"], 1.0 / float(info.get("fps") or fps or 30.0)),
    )


def auto_train_fraction(n_frames: int, frequency_hz: float, fps: float, src: str = "<clip>") -> float:
    """The training share of a contiguous split that leaves :data:`HELD_OUT_PERIODS` periods held out.

    ``1 - (HELD_OUT_PERIODS periods + 3 frames) / n_frames``, at most :data:`TRAIN_FRACTION_MAX`
    (the default split); a frequency that cannot be read leaves the default.

    Raises:
        ClipError: naming ``src`` when the training part would fall below
            :data:`TRAIN_FRACTION_MIN` of the clip (too short for its own frequency).
    """
    if not (np.isfinite(frequency_hz) and frequency_hz > 0 and fps > 0):
        return TRAIN_FRACTION_MAX
    need = HELD_OUT_PERIODS * fps / frequency_hz + 3
    frac = min(TRAIN_FRACTION_MAX, 1.0 - need / n_frames)
    if frac < TRAIN_FRACTION_MIN:
        raise ClipError(
            f"{src}: too short for its motion: {n_frames} frames at {fps:g} fps hold {n_frames * frequency_hz / fps:.1f} periods of "
            f"{frequency_hz:.2f} Hz; the evaluation needs {HELD_OUT_PERIODS:g} held-out periods and Stage 2 as many again to train "
            f"(about {int(np.ceil(2 * need))} frames)"
        )
    return float(frac)
