"""Frames predicted by the original GaussianPrediction (Zhao et al., SIGGRAPH 2024), imported to be scored like GP-2D.

The original code needs a GPU; a user who runs it on the clip (trained on the frames before the
held-out segment, forecasting from there) renders its predictions from the training camera and
brings them here. The layout is a folder of images (png, jpg, jpeg or bmp) and a ``times.csv``
beside them with a header ``file,time_s`` and one row per predicted frame: the image's file name in
the folder and its time on the clip's clock (seconds, the ``t`` of ``clip.npz``). The rows must be
the held-out segment's frame times, in order, from its first frame, one frame period apart; more
rows than the segment are a longer free prediction, whose first and last natural period give the
amplitude row (over the length it covers).

Every defect stops the import with one line naming the file: a missing ``times.csv`` or a
malformed row, a listed image that is missing or unreadable, an image of another size than the
clip's frames, and a time that does not follow one frame period after the previous (a missing
or misnumbered frame) or does not start at the held-out segment.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from lagsplat.io.clip import ClipError
from lagsplat.io.images import read_image

__all__ = ["load_prediction_frames", "prediction_arrays"]


def load_prediction_frames(folder: str | Path, t0: float, dt: float, height: int, width: int, min_frames: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """Read and check a folder of predicted frames (layout of the module docstring).

    Args:
        folder: the folder holding the images and ``times.csv``.
        t0: time of the held-out segment's first frame, s.
        dt: the clip's frame period, s.
        height, width: the clip's frame size, pixels.
        min_frames: fewest frames accepted.

    Returns:
        ``(frames uint8 [n,H,W,3], t [n] s)``.

    Raises:
        ClipError: one line naming the file and what is wrong.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise ClipError(f"{folder}: not a folder of predicted frames")
    times = folder / "times.csv"
    if not times.is_file():
        raise ClipError(f"{times}: missing (one row 'file,time_s' per predicted frame)")
    rows: list[tuple[str, float]] = []
    with times.open(newline="") as fh:
        reader = csv.reader(fh)
        head = next(reader, None)
        if head is None or [h.strip() for h in head[:2]] != ["file", "time_s"]:
            raise ClipError(f"{times}: the first line must be the header 'file,time_s', got {head!r}")
        for line, row in enumerate(reader, start=2):
            if not row or not "".join(row).strip():
                continue
            try:
                name, t = row[0].strip(), float(row[1])
            except (IndexError, ValueError):
                raise ClipError(f"{times} line {line}: expected 'file,time_s', got {','.join(row)!r}") from None
            if not math.isfinite(t):
                raise ClipError(f"{times} line {line}: time {row[1]!r} is not a finite number")
            rows.append((name, t))
    if len(rows) < min_frames:
        raise ClipError(f"{times}: {len(rows)} predicted frames listed, at least {min_frames} needed")
    frames = np.empty((len(rows), height, width, 3), np.uint8)
    prev = None
    for i, (name, t) in enumerate(rows):
        path = folder / name
        if prev is None and abs(t - t0) > 0.5 * dt:
            raise ClipError(f"{path}: the first predicted frame is at {t:.4g} s, the held-out segment starts at {t0:.4g} s")
        if prev is not None and abs((t - prev) - dt) > 0.25 * dt:
            raise ClipError(f"{path}: at {t:.4g} s after {prev:.4g} s; predicted frames must be {dt:.4g} s apart (a missing or misnumbered frame)")
        if not path.is_file():
            raise ClipError(f"{path}: listed in {times.name} but missing")
        img = read_image(path)
        if img.shape[:2] != (height, width):
            raise ClipError(f"{path}: {img.shape[1]}x{img.shape[0]} pixels, the clip's frames are {width}x{height}")
        frames[i], prev = img, t
    return frames, np.array([t for _, t in rows])


def prediction_arrays(frames: np.ndarray, n_held_out: int, m_period: int) -> tuple[np.ndarray, np.ndarray | None, float]:
    """Split imported predictions into the protocol's held-out frames and long-prediction ends.

    Args:
        frames: uint8 ``[n,H,W,3]`` from :func:`load_prediction_frames`.
        n_held_out: frames of the held-out segment.
        m_period: frames of one natural period.

    Returns:
        ``(held_out [n_held_out,...], long_ends [2 m_period,...] or None, long horizon in frames)``: the long ends need
        at least two periods of prediction past the held-out segment.

    Raises:
        ClipError: with fewer predicted frames than the held-out segment.
    """
    if len(frames) < n_held_out:
        raise ClipError(f"{len(frames)} predicted frames do not cover the {n_held_out}-frame held-out segment")
    if len(frames) < n_held_out + 2 * m_period:
        return frames[:n_held_out], None, float(len(frames))
    return frames[:n_held_out], np.concatenate([frames[:m_period], frames[-m_period:]]), float(len(frames))
