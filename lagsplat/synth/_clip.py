"""Argument checks and the contiguous split shared by the synthetic clip factories.

Used by :func:`~lagsplat.synth.pendulum.make_pendulum_clip` and
:func:`~lagsplat.synth.coupled_carts_clip.make_coupled_carts_clip`, so both reject
the same arguments with the same messages.
"""

from __future__ import annotations

import math
from typing import Any


def check_timing(fps: Any, duration_s: Any) -> tuple[float, float]:
    """``(fps, duration_s)`` as floats: frame rate (Hz) and length (s).

    Raises:
        ValueError: if either is not finite and positive.
    """
    fps_f = float(fps)
    dur = float(duration_s)
    if not (math.isfinite(fps_f) and fps_f > 0):
        raise ValueError(f"fps must be positive, got {fps!r}")
    if not (math.isfinite(dur) and dur > 0):
        raise ValueError(f"duration_s must be positive, got {duration_s!r}")
    return fps_f, dur


def check_train_fraction(train_fraction: Any) -> float:
    """The training share as a float.

    Raises:
        ValueError: if it is not in ``(0, 1)``.
    """
    tf = float(train_fraction)
    if not (0.0 < tf < 1.0):
        raise ValueError(f"train_fraction must be in (0, 1), got {train_fraction!r}")
    return tf


def contiguous_train_frames(train_fraction: float, n_frames: int) -> int:
    """Number of training frames, ``int(train_fraction * n_frames)``, of a contiguous split.

    The first that many frames train, the rest are held out.

    Raises:
        ValueError: if the split leaves fewer than 2 training or 8 held-out frames.
    """
    T = n_frames
    n_train = int(train_fraction * T)
    if n_train < 2 or T - n_train < 8:
        raise ValueError(
            f"split leaves {n_train} training and {T - n_train} held-out frames of {T}; "
            "need at least 2 and 8 (increase duration_s or fps, or change train_fraction)"
        )
    return n_train
