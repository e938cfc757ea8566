"""Read a folder of still images as a clip.

Files with the extensions ``.png``, ``.jpg``, ``.jpeg`` and ``.bmp`` (any
case; hidden files starting with ``.`` are ignored) are the frames, in
*natural* name order (``frame2`` before ``frame10``). Image files carry no
timestamps, so the capture rate must be stated: ``t_i = i / fps``.
Grayscale images are replicated to RGB, an alpha channel is dropped and
16-bit images are scaled to 8 bits.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from lagsplat.io.common import FrameCollector, FrameTransform, check_range, cv_to_rgb, natural_key, validate_range
from lagsplat.io.clip import ClipError

__all__ = ["read_image_folder", "read_image", "IMAGE_EXTENSIONS", "list_image_files"]

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp")
"""Image file extensions (lower case) read by :func:`read_image_folder`."""


def list_image_files(path: str | Path) -> list[Path]:
    """Image files of a folder in natural name order (see module docstring).

    Raises:
        ClipError: if ``path`` is missing or not a folder.
    """
    path = Path(path)
    if not path.exists():
        raise ClipError(f"{path}: file not found")
    if not path.is_dir():
        raise ClipError(f"{path}: not a folder of images")
    files = [
        p for p in path.iterdir()
        if p.is_file() and not p.name.startswith(".") and p.suffix.lower() in IMAGE_EXTENSIONS
    ]
    return sorted(files, key=lambda p: natural_key(p.name))


def read_image(p: Path) -> np.ndarray:
    """One image file as uint8 RGB ``[H,W,3]`` (conversions of the module docstring).

    Raises:
        ClipError: naming the file, if it cannot be read or decoded.
    """
    try:
        buf = np.fromfile(p, dtype=np.uint8)
        img = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED) if buf.size else None
    except (OSError, cv2.error) as exc:
        raise ClipError(f"{p}: cannot read image ({exc})") from exc
    if img is None:
        raise ClipError(f"{p}: cannot decode image (corrupt or not an image)")
    return cv_to_rgb(img, str(p))


def read_image_folder(
    path: str | Path,
    fps: float | None,
    *,
    start: int = 0,
    stop: int | None = None,
    transform: FrameTransform | None = None,
) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """Read a folder of images as frames captured at ``fps``.

    Args:
        path: folder holding png / jpg / jpeg / bmp files.
        fps: capture rate in Hz (required; ``system.source.fps``).
        start, stop: keep only images ``[start, stop)`` of the sorted list
            (``stop=None``: to the end); only those are decoded.
        transform: optional per-frame function (uint8 ``[H, W, 3]`` -> uint8
            ``[h, w, 3]``), e.g. crop + resize.

    Returns:
        ``(frames, t, info)``: frames uint8 ``[T, h, w, 3]`` RGB; ``t`` float64
        ``[T]`` = ``arange(T) / fps`` seconds; ``info`` with ``rule``
        (``"config_fps"``), ``fps``, ``n_files``, ``first_file``,
        ``last_file``, native ``width`` / ``height``, ``frames`` and an empty
        ``warnings`` list.

    Raises:
        ClipError: if ``fps`` is None (``"<path>: image folders carry no
            timestamps; set system.source.fps"``) or not positive, the folder
            is missing or holds no image, an image cannot be decoded, or an
            image's size differs from the first one (the message starts with
            the offending file).
    """
    path = Path(path)
    src = str(path)
    start, stop = validate_range(src, start, stop)
    files = list_image_files(path)
    if fps is None:
        raise ClipError(f"{src}: image folders carry no timestamps; set system.source.fps")
    try:
        f = float(fps)
    except (TypeError, ValueError):
        f = float("nan")
    if not math.isfinite(f) or f <= 0:
        raise ClipError(f"{src}: system.source.fps must be a positive number of frames per second, got {fps!r}")
    if not files:
        raise ClipError(f"{src}: no image files ({', '.join(IMAGE_EXTENSIONS)}) in this folder")
    start, stop_ = check_range(src, start, stop, len(files))

    collector = FrameCollector(src, start, stop_, transform)
    for i in range(start, stop_):
        collector.add(i, read_image(files[i]), name=str(files[i]))
    frames = collector.result()
    T = frames.shape[0]
    assert collector.native_shape is not None
    info = {
        "reader": "images",
        "rule": "config_fps",
        "fps": f,
        "container_fps": None,
        "n_files": len(files),
        "first_file": files[start].name,
        "last_file": files[stop_ - 1].name,
        "width": collector.native_shape[1],
        "height": collector.native_shape[0],
        "frames": [start, stop_],
        "warnings": [],
    }
    return frames, np.arange(T, dtype=np.float64) / f, info
