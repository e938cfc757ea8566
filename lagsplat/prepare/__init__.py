"""Automatic clip preparation: the object, its region, the working resolution and the split, read off the motion.

A user's video shows a small moving object in a large, mostly static scene,
often with other things moving too. Stage 1 learns whatever is cheapest under
the photometric loss (paper App. C), so the object should fill a good part of
the frame, at a resolution where its smallest part still spans a few pixels,
and the held-out part of the clip must hold enough periods for the evaluation
(paper §4.1). :func:`prepare_video` reads the clip once at low resolution
(inside the user's ``crop`` when one is set) and decides, from the motion:

* which moving part is the oscillating object, and which parts (people, hands,
  doors) to set aside (:mod:`lagsplat.prepare.parts`);
* whether the object's motion is of the model's class (:mod:`lagsplat.prepare.analysis`);
* the region of interest and the working resolution: the box's long side at
  64, 96 or 128 px, the smallest at which the object's typical extent spans
  :data:`MIN_OBJECT_PX` pixels (never above the native resolution);
* the motion's frequency, along the principal direction of the object's path,
  over the frames where it moves (:mod:`lagsplat.prepare.frequency`), which
  sets the split (:func:`auto_split`).

Every choice is overridden by setting it (``crop``, ``resize``,
``split.train_fraction``); :mod:`lagsplat.ingest` applies the result, records
it in ``meta["prepare"]`` and can draw it (:mod:`lagsplat.prepare.preview`).
"""

from __future__ import annotations

import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from lagsplat.io.clip import ClipError
from lagsplat.io.video import read_video
from lagsplat.prepare.stabilise import stabilise as take_out_sway, to_native
from lagsplat.prepare.analysis import PreparationRefused, analyse_motion, image_winding

__all__ = [
    "Preparation", "PreparationRefused", "prepare_video", "analyse_motion", "image_winding", "auto_split", "auto_train_fraction",
    "MIN_OBJECT_PX", "LONG_SIDES", "HELD_OUT_PERIODS", "MIN_IDENTIFY_PERIODS", "ANALYSIS_PX",
]  # fmt: skip

#: Smallest extent (px) of the moving object at the working resolution that the resolution choice aims for.
MIN_OBJECT_PX = 8.0
#: Candidate long sides (px) of the working resolution, smallest first.
LONG_SIDES = (64, 96, 128)
#: Periods of the motion the automatic split keeps for the held-out part: the evaluation's two-period
#: horizon (``evaluate.n_periods``) and one period of room for its windows.
HELD_OUT_PERIODS = 3.0
#: The automatic split's training share: at most (the default split) and at least.
TRAIN_FRACTION_MAX, TRAIN_FRACTION_MIN = 0.8, 0.5
#: Fewer periods of motion than this cannot be identified (below it a frequency and a decay are not both read).
MIN_IDENTIFY_PERIODS = 2.0
#: Long side (px) of the frames the analysis reads.
ANALYSIS_PX = 160


@dataclass
class Preparation:
    """What :func:`prepare_video` chose, and why.

    Attributes:
        crop: ``[x0, y0, x1, y1]`` native pixels, or ``None`` (keep the whole frame).
        resize: ``[width, height]`` of the working frames, pixels.
        native_size: ``[W, H]`` of the source.
        moving_fraction: share of the analysed frame whose pixels belong to the object's motion.
        object_px: the object's typical extent at the working resolution, px (square root of its area).
        motion_snr: largest temporal standard deviation over the noise floor.
        leaving_fraction: share of frames in which the object shrinks at the image border.
        frequency_hz: the object's frequency over the frames where it moves, along its path's principal direction, Hz.
        peak_share: share of the path's power in the periodogram's peak (1: a pure oscillation).
        periods: periods of motion over the frames where it moves.
        moving_s: ``[start, stop]`` s (clip time) over which the object moves; a motion that comes to rest stops early.
        dropped: one sentence per moving part set aside (where, and why).
        note: a remark on the choice (e.g. no part oscillates clearly), or ``None``.
        user_crop: whether ``crop`` was the user's (the analysis read inside it).
        camera: ``[T][2][3]`` (nested lists) similarity transforms (native px of the whole frame) that take each kept
            frame into the first one's picture, where a hand-held camera's sway was taken out
            (:mod:`lagsplat.prepare.stabilise`); ``None`` for a still camera.
    """

    crop: list[int] | None
    resize: list[int]
    native_size: list[int]
    moving_fraction: float
    object_px: float
    motion_snr: float
    leaving_fraction: float
    frequency_hz: float = float("nan")
    peak_share: float = float("nan")
    periods: float = float("nan")
    moving_s: list[float] = field(default_factory=list)
    dropped: list[str] = field(default_factory=list)
    note: str | None = None
    user_crop: bool = False
    camera: list | None = None

    def as_dict(self) -> dict[str, Any]:
        """JSON-serialisable form (``clip.meta["prepare"]``)."""
        return asdict(self)

    def summary(self) -> str:
        """What was chosen, for the log (one line, then one per part set aside)."""
        crop = "whole frame" if self.crop is None else f"{'your' if self.user_crop else ''} crop {self.crop}".strip()
        moving = ""
        if len(self.moving_s) == 2:
            moving = f" while it moves, {self.moving_s[0]:.1f}-{self.moving_s[1]:.1f} s"
        line = (
            f"{crop} of {self.native_size[0]}x{self.native_size[1]}, resize {self.resize[0]}x{self.resize[1]} "
            f"(object about {self.object_px:.0f} px across, motion {self.motion_snr:.0f}x the noise floor, "
            f"about {self.frequency_hz:.2f} Hz{moving})"
        )
        extra = ([self.note] if self.note else []) + [f"set aside {d}" for d in self.dropped]
        return "\n".join([line] + [f"  {e}" for e in extra])


def _reader_transform(long_side: int, crop: list[int] | None):
    """A frame transform: the user's crop (native px), then at most ``long_side`` px on the long side (``cv2.INTER_AREA``)."""

    def transform(frame: np.ndarray) -> np.ndarray:
        if crop is not None:
            frame = frame[crop[1] : crop[3], crop[0] : crop[2]]
        h, w = frame.shape[:2]
        s = min(1.0, long_side / max(h, w))
        if s >= 1.0:
            return np.ascontiguousarray(frame)
        return cv2.resize(frame, (max(1, round(w * s)), max(1, round(h * s))), interpolation=cv2.INTER_AREA)

    return transform


def prepare_video(
    path: str | Path,
    fps: float | None = None,
    start: int = 0,
    stop: int | None = None,
    crop: list[int] | None = None,
    preview: str | Path | None = None,
    stabilise: bool = True,
    **timing: float,
) -> Preparation:
    """Choose the object, the region of interest and the working resolution of a video from its motion (module docstring).

    Args:
        path: the video file.
        fps, timing: as :func:`lagsplat.io.video.read_video` (``max_fps``, ``jitter_tol``).
        start, stop: the frame range ``[start, stop)`` the clip keeps.
        crop: a region of interest given by the user (``[x0, y0, x1, y1]`` native px): kept, the analysis
            reads inside it, and the resolution is chosen for it.
        preview: where to draw what was chosen (PNG, :func:`lagsplat.prepare.preview.draw_preview`), also
            when the clip is refused; ``None``: no drawing.
        stabilise: read a hand-held camera's sway and take it out where that stills the picture
            (:func:`lagsplat.prepare.stabilise.stabilise`); ``False``: read the frames as they are.

    Returns:
        The :class:`Preparation`.

    Raises:
        ClipError: as :func:`lagsplat.prepare.analysis.analyse_motion` (a :class:`PreparationRefused`), naming
            the file and the setting to change; a crop outside the frame.
    """
    src = str(path)
    with warnings.catch_warnings():  # the timing warnings come again when the clip is read
        warnings.simplefilter("ignore")
        small, t, info = read_video(path, fps=fps, start=start, stop=stop, transform=_reader_transform(ANALYSIS_PX, crop), **timing)
    native = [int(info.get("width") or small.shape[2]), int(info.get("height") or small.shape[1])]
    if crop is not None and (crop[2] > native[0] or crop[3] > native[1]):
        raise ClipError(f"{src}: crop {crop} lies outside the {native[0]}x{native[1]} frame (set `crop` inside it)")
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 1.0 / float(fps or 30.0)
    try:
        small, m, camera, camera_note = _analyse(small, src, dt, stabilise)
    except PreparationRefused as e:
        if preview is not None:
            _draw(preview, e.analysis, dt, str(e))
        raise
    h, w = small.shape[1:3]
    base = [0, 0] if crop is None else crop[:2]
    field_w = native[0] if crop is None else crop[2] - crop[0]
    s = field_w / w  # native px per analysis px
    user_crop = crop is not None
    if crop is None:
        x0, y0, x1, y1 = m["box"]
        pad = max(2.0, 0.15 * max(x1 - x0, y1 - y0))
        x0, y0 = max(0.0, x0 - pad), max(0.0, y0 - pad)
        x1, y1 = min(float(w), x1 + pad), min(float(h), y1 + pad)
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
    a, b = m["span"]
    prep = Preparation(
        crop=crop,
        resize=[max(8, int(round(cw * k))), max(8, int(round(ch * k)))],
        native_size=native,
        moving_fraction=float(m["changing"].mean()),
        object_px=float(extent_native * k),
        motion_snr=float(m["snr"]),
        leaving_fraction=float(m["leaving_fraction"]),
        frequency_hz=float(m["frequency_hz"]),
        peak_share=float(m["peak_share"]),
        periods=float(m["periods"]),
        moving_s=[float(t[a] - t[0]), float(t[b - 1] - t[0])],
        dropped=list(m["dropped"]),
        note="; ".join(n for n in (camera_note, m["note"]) if n) or None,
        user_crop=user_crop,
        camera=None if camera is None else to_native(camera, s, (float(base[0]), float(base[1]))).round(4).tolist(),
    )
    if preview is not None:
        m["crop_in_analysis"] = None if crop is None or user_crop else [(crop[0] - base[0]) / s, (crop[1] - base[1]) / s, (crop[2] - base[0]) / s, (crop[3] - base[1]) / s]
        _draw(preview, m, dt, prep.summary())
    return prep


def _oscillates(m: dict[str, Any]) -> bool:
    """Whether an analysis found an oscillating object (:attr:`lagsplat.prepare.parts.Part.oscillates`)."""
    return bool(m.get("kept")) and m["kept"][0].oscillates


def _analyse(small: np.ndarray, src: str, dt: float, stabilise: bool) -> tuple[np.ndarray, dict[str, Any], np.ndarray | None, str | None]:
    """:func:`lagsplat.prepare.analysis.analyse_motion` of the frames with the camera's sway taken out
    (:func:`lagsplat.prepare.stabilise.stabilise`), or as they are: a "sway" fitted to an object that fills
    the frame (branches against the sky) is the object's own motion, and warping it out leaves no oscillation;
    where the stabilised frames show no oscillating object (or are refused) and the frames as they are show
    one, those are read.

    Returns:
        ``(frames, analysis, transforms or None, note or None)``.

    Raises:
        PreparationRefused: as :func:`~lagsplat.prepare.analysis.analyse_motion`, for the frames read.
    """
    warped, camera, note = take_out_sway(small) if stabilise else (small, None, None)
    if camera is None:
        return small, analyse_motion(small, src, dt), None, None
    try:
        m = analyse_motion(warped, src, dt)
    except PreparationRefused as e:
        m, refused = e.analysis, e
    else:
        refused = None
    if refused is None and _oscillates(m):
        return warped, m, camera, note
    try:
        m_raw = analyse_motion(small, src, dt)
    except PreparationRefused:
        m_raw = None
    if m_raw is not None and _oscillates(m_raw):
        return small, m_raw, None, None
    if refused is not None:
        raise refused
    return warped, m, camera, note


def _draw(path: str | Path, analysis: dict[str, Any], dt: float, title: str) -> None:
    """Draw the preview; a drawing failure is reported, never fatal (the clip itself is fine)."""
    from lagsplat.prepare.preview import draw_preview

    try:
        draw_preview(path, analysis, dt, title)
    except Exception as exc:  # noqa: BLE001 - a figure must not stop the ingest
        warnings.warn(f"{path}: the preparation preview could not be drawn: {exc}", stacklevel=2)


def auto_split(n_frames: int, frequency_hz: float, fps: float, periods: float | None = None, src: str = "<clip>") -> tuple[float, str | None]:
    """The training share of a contiguous split that leaves :data:`HELD_OUT_PERIODS` periods held out.

    ``1 - (HELD_OUT_PERIODS periods + 3 frames) / n_frames``, at most :data:`TRAIN_FRACTION_MAX` (the default
    split). A clip whose training part would fall below :data:`TRAIN_FRACTION_MIN` (too short for the paper's
    3 + 3 period protocol) is identified on all its frames: the share is 1 and the note says
    ``"no held-out validation (N periods)"``. A frequency that cannot be read leaves the default split.

    Args:
        n_frames: frames in the clip.
        frequency_hz: the motion's frequency, Hz.
        fps: frame rate, Hz.
        periods: periods of motion over the frames where the object moves (default: the whole clip's).
        src: the file, named in the error.

    Returns:
        ``(train_fraction, note)``; ``note`` is ``None`` for a held-out split.

    Raises:
        ClipError: naming ``src`` and ``frames`` when the motion holds fewer than :data:`MIN_IDENTIFY_PERIODS` periods.
    """
    if not (np.isfinite(frequency_hz) and frequency_hz > 0 and fps > 0):
        return TRAIN_FRACTION_MAX, None
    clip_periods = n_frames * frequency_hz / fps
    moving = clip_periods if periods is None or not np.isfinite(periods) else min(float(periods), clip_periods)
    need = HELD_OUT_PERIODS * fps / frequency_hz + 3
    frac = min(TRAIN_FRACTION_MAX, 1.0 - need / n_frames)
    if moving < MIN_IDENTIFY_PERIODS:
        raise ClipError(
            f"{src}: too short to identify: {n_frames} frames at {fps:g} fps hold {moving:.1f} periods of motion at {frequency_hz:.2f} Hz; "
            f"at least {MIN_IDENTIFY_PERIODS:g} are needed (set `frames` to a longer range of the recording)"
        )
    if frac >= TRAIN_FRACTION_MIN:
        return float(frac), None
    return 1.0, f"no held-out validation ({clip_periods:.1f} periods)"


def auto_train_fraction(n_frames: int, frequency_hz: float, fps: float, src: str = "<clip>", periods: float | None = None) -> float:
    """The training share of :func:`auto_split` (1 for a clip identified without held-out frames).

    Raises:
        ClipError: as :func:`auto_split`.
    """
    return auto_split(n_frames, frequency_hz, fps, periods, src)[0]
