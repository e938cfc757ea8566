"""Helpers shared by the readers of :mod:`lagsplat.io` (not public API)."""

from __future__ import annotations

import math
import os
import re
import subprocess
from pathlib import Path
from typing import Any, Callable

import cv2
import numpy as np

from lagsplat.io.clip import ClipError

FrameTransform = Callable[[np.ndarray], np.ndarray]
"""Per-frame transform: uint8 ``[H, W, 3]`` RGB -> uint8 ``[h, w, 3]`` RGB."""

_DIGITS = re.compile(r"(\d+)")


def natural_key(name: str) -> tuple:
    """Sort key that orders embedded numbers numerically (``frame2 < frame10``)."""
    parts = _DIGITS.split(name)
    return tuple((0, int(p), p) if p.isdigit() else (1, p.lower(), p) for p in parts)


def cv_to_rgb(img: np.ndarray, source: str) -> np.ndarray:
    """Convert an OpenCV-decoded image to uint8 ``[H, W, 3]`` RGB.

    Accepts gray ``[H, W]`` / ``[H, W, 1]`` (replicated), BGR ``[H, W, 3]`` and
    BGRA ``[H, W, 4]`` (alpha dropped); uint16 is rescaled to 8 bits by
    ``round(x / 257)``.

    Raises:
        ClipError: for any other dtype or channel count.
    """
    if img.dtype == np.uint16:
        img = ((img.astype(np.uint32) + 128) // 257).astype(np.uint8)
    elif img.dtype != np.uint8:
        raise ClipError(f"{source}: unsupported pixel type {img.dtype} (need 8- or 16-bit images)")
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim == 2:
        return cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_GRAY2RGB)
    if img.ndim == 3 and img.shape[2] == 3:
        return cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_BGR2RGB)
    if img.ndim == 3 and img.shape[2] == 4:
        return cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_BGRA2RGB)
    raise ClipError(f"{source}: unsupported image shape {img.shape}")


def check_range(source: str, start: int, stop: int | None, n: int) -> tuple[int, int]:
    """Resolve a ``[start, stop)`` frame range against ``n`` available frames.

    Returns:
        ``(start, stop)`` with ``stop`` an int.

    Raises:
        ClipError: if the range is negative, empty or reaches beyond ``n``.
    """
    stop_ = n if stop is None else int(stop)
    if start < 0 or stop_ < 0:
        raise ClipError(f"{source}: frame range [{start}, {stop}) must not be negative")
    if stop_ > n:
        raise ClipError(f"{source}: frame range [{start}, {stop}) goes beyond the {n} frames of the source")
    if start >= stop_:
        raise ClipError(f"{source}: frame range [{start}, {stop}) selects no frames (the source has {n})")
    return int(start), stop_


def validate_range(source: str, start: Any, stop: Any) -> tuple[int, int | None]:
    """Check the types of a frame range before reading. Raises ClipError."""
    try:
        s = int(start)
        e = None if stop is None else int(stop)
        if s != start or (e is not None and e != stop):
            raise ValueError
    except (TypeError, ValueError):
        raise ClipError(f"{source}: frame range must be two integers [start, stop), got [{start!r}, {stop!r}]") from None
    if s < 0 or (e is not None and e < 0):
        raise ClipError(f"{source}: frame range [{s}, {e}) must not be negative")
    if e is not None and e <= s:
        raise ClipError(f"{source}: frame range [{s}, {e}) selects no frames")
    return s, e


class FrameCollector:
    """Keep the frames of a ``[start, stop)`` range, transformed one by one.

    Frames outside the range are dropped immediately, so memory holds only
    the (possibly cropped / resized) frames that end up in the clip.
    """

    def __init__(self, source: str, start: int = 0, stop: int | None = None,
                 transform: FrameTransform | None = None, capacity: int | None = None) -> None:
        """``capacity``: expected number of kept frames, if known; the frames
        are then written into one preallocated array (no copy at the end)."""
        self.source = source
        self.start = int(start)
        self.stop = stop
        self.transform = transform
        self.capacity = capacity if capacity and capacity > 0 else None
        self.buffer: np.ndarray | None = None
        self.n_buffered = 0
        self.frames: list[np.ndarray] = []
        self.native_shape: tuple[int, int] | None = None

    def wants(self, i: int) -> bool:
        """True if frame ``i`` lies in the range."""
        return i >= self.start and (self.stop is None or i < self.stop)

    def add(self, i: int, frame: np.ndarray, name: str | None = None) -> None:
        """Offer frame ``i`` (uint8 ``[H, W, 3]`` RGB); kept if in range.

        Raises:
            ClipError: if its native size differs from the first kept frame.
        """
        if not self.wants(i):
            return
        hw = (int(frame.shape[0]), int(frame.shape[1]))
        if self.native_shape is None:
            self.native_shape = hw
        elif hw != self.native_shape:
            who = name or f"frame {i}"
            raise ClipError(
                f"{who}: size {hw[1]}x{hw[0]} differs from the first frame's "
                f"{self.native_shape[1]}x{self.native_shape[0]}"
            )
        if self.transform is not None:
            frame = self.transform(frame)
            if frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape[2] != 3:
                raise ClipError(f"{self.source}: frame transform must return uint8 [H,W,3], got {frame.dtype} {frame.shape}")
        if self.capacity is not None and self.buffer is None and not self.frames:
            self.buffer = np.empty((self.capacity, *frame.shape), np.uint8)
        if self.buffer is not None and not self.frames and self.n_buffered < self.capacity \
                and frame.shape == self.buffer.shape[1:]:
            self.buffer[self.n_buffered] = frame
            self.n_buffered += 1
        else:
            self.frames.append(np.ascontiguousarray(frame))

    def result(self) -> np.ndarray:
        """Return the kept frames as uint8 ``[T, h, w, 3]``.

        Raises:
            ClipError: if the transform returned frames of different sizes.
        """
        parts = []
        if self.buffer is not None:
            parts.append(self.buffer[: self.n_buffered])
        parts.extend(f[None] for f in self.frames)
        self.buffer, self.frames = None, []
        if not parts:
            return np.zeros((0, 0, 0, 3), np.uint8)
        if len(parts) == 1:
            return parts[0]
        if len({p.shape[1:] for p in parts}) > 1:
            raise ClipError(f"{self.source}: frames of different sizes after the frame transform")
        return np.concatenate(parts)


def jsonable(obj: Any) -> Any:
    """Recursively convert numpy scalars/arrays and paths to JSON types."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return jsonable(obj.item())
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, Path):
        return str(obj)
    return obj


def warp_to_reference(frame: np.ndarray, A: np.ndarray) -> np.ndarray:
    """``frame [H, W, 3]`` uint8 warped by the ``2 x 3`` affine ``A`` (its px to the reference frame's px):
    bilinear, edges replicated (``cv2.warpAffine``). The one rule the stabiliser's analysis and the reader share."""
    H, W = frame.shape[:2]
    return cv2.warpAffine(frame, A, (W, H), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def frame_transform(src: str, crop: list[int] | None, resize: list[int] | None, camera: list | None = None) -> FrameTransform | None:
    """The reader's per-frame transform, ``None`` when there is nothing to do. Per kept frame, in reading
    order: the camera's sway taken out (``camera[i]``, a ``2 x 3`` similarity of native px, from
    :mod:`lagsplat.prepare.stabilise`; :func:`warp_to_reference`), then the crop ``[x0, y0, x1, y1]``
    (native px), then the resize ``[width, height]`` (``cv2.INTER_AREA``).

    Raises (when called):
        ClipError: naming ``src``: a crop outside the frame, or more frames than ``camera`` holds.
    """
    if crop is None and resize is None and camera is None:
        return None
    warps = None if camera is None else np.asarray(camera, np.float64)
    kept = [0]

    def transform(frame: np.ndarray) -> np.ndarray:
        if warps is not None:
            i = kept[0]
            if i >= len(warps):
                raise ClipError(f"{src}: the clip has more frames than its camera motion was read for ({len(warps)}); read it again")
            frame = warp_to_reference(frame, warps[i])
            kept[0] = i + 1
        if crop is not None:
            H, W = frame.shape[:2]
            x0, y0, x1, y1 = crop
            if not (0 <= x0 < x1 <= W and 0 <= y0 < y1 <= H):
                raise ClipError(
                    f"{src}: crop {crop} (x0 y0 x1 y1) lies outside the {W}x{H} frame or is empty"
                )
            frame = frame[y0:y1, x0:x1]
        if resize is not None:
            frame = cv2.resize(frame, (resize[0], resize[1]), interpolation=cv2.INTER_AREA)
        return np.ascontiguousarray(frame)

    return transform


def code_commit(where: str | Path | None = None) -> dict[str, Any] | None:
    """The git commit of the lagsplat checkout (``{"commit", "dirty"}``, the full hash), or ``None`` when it is not a git
    checkout or git is missing. ``dirty``: tracked files differ from the commit."""
    root = Path(where) if where is not None else Path(__file__).resolve().parents[2]
    env = {**os.environ, "GIT_OPTIONAL_LOCKS": "0"}  # read-only: git status does not rewrite the index
    try:
        head = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], env=env, capture_output=True, text=True, timeout=20)
        if head.returncode != 0:
            return None
        status = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"], env=env, capture_output=True, text=True, timeout=20)
    except (OSError, subprocess.SubprocessError):
        return None
    return {"commit": head.stdout.strip(), "dirty": bool(status.stdout.strip()) if status.returncode == 0 else None}
