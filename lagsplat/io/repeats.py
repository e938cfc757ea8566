"""Repeated frames: a recording converted to a higher frame rate shows each captured frame more than once.

A phone video edited and exported at 60 fps from 30-fps footage (or a 24-fps film
shown at 60 by 3:2 pulldown, or a screen capture) repeats frames: between a frame
and its repeat nothing moves, between the repeat and the next captured frame the
object moves twice as far. A chart read on such a clip has a speed that drops to
zero every other step (paper §3.2's continuity check fails on it) and a velocity
that the Lagrangian cannot follow. :func:`repeated_frames` finds the repeats by
their pattern: a frame whose change from the one before is a small fraction of
its neighbours' changes, on a good share of the clip (a motion that comes to rest
changes little on a whole run of frames, not every other one), and where they
alternate with captured frames, by the parity of the frame index, run by run
(a turning point, where the object barely moves, hides the pattern from the
change alone; a dropped frame in the source flips the parity); :func:`drop_repeats`
keeps the captured frames and spaces them evenly over the time they span (the
capture was even; the repeats are what made the displayed times uneven).
"""

from __future__ import annotations

import numpy as np

__all__ = ["repeated_frames", "drop_repeats", "REPEAT_RATIO", "MIN_REPEAT_SHARE"]

#: A frame repeats the one before when its change from it is below this fraction of the larger of its neighbours' changes.
REPEAT_RATIO = 0.25
#: ... and repeats are a pattern of the clip only from this share of its frames on.
MIN_REPEAT_SHARE = 0.2
#: The captured frames must be spaced within this factor of their mean interval (else the repeats are left in).
MAX_GAP = 2.0


def _changes(images: np.ndarray) -> np.ndarray:
    """``[T-1]`` mean absolute change of the grey image from each frame to the next (grey levels)."""
    step = max(1, int(np.ceil(max(images.shape[1:3]) / 160)))  # a thumbnail is enough to see change
    g = images[:, ::step, ::step].astype(np.float32)
    g = g.mean(-1) if g.ndim == 4 else g
    return np.abs(np.diff(g, axis=0)).mean((1, 2))


def repeated_frames(images: np.ndarray) -> np.ndarray:
    """``[T]`` bool: the frames that repeat the one before (module docstring); all ``False`` when repeats are not a
    pattern of the clip (fewer than :data:`MIN_REPEAT_SHARE` of the frames).

    Args:
        images: ``[T, H, W, 3]`` (or ``[T, H, W]``) frames.
    """
    T = len(images)
    rep = np.zeros(T, bool)
    if T < 4:
        return rep
    d = _changes(images)  # d[i-1]: frame i against frame i-1
    pad = np.r_[0.0, 0.0, d, 0.0, 0.0]
    nb = np.max([pad[k : k + len(d)] for k in (0, 1, 3, 4)], axis=0)  # the largest change within two frames (a frame shown 3 times)
    rep[1:] = d < REPEAT_RATIO * nb
    rep[1:] &= nb > 0
    if rep.mean() < MIN_REPEAT_SHARE:
        return np.zeros(T, bool)
    return _every_other(rep)


def _every_other(rep: np.ndarray, half: int = 8) -> np.ndarray:
    """Where the repeats found by their change alternate with captured frames (one parity of frame index holds at least
    3 of them within ``half`` frames either side, the other at most 1), decide by that parity: near a turning point
    the object barely moves and the change alone misses repeats or flags captured frames. A frame where no parity
    leads takes the parity of the nearest frame where one does; a clip where parity leads on under half of the
    frames (another pattern, e.g. 3:2 pulldown) keeps the change's reading."""
    T = len(rep)
    idx = np.arange(T)
    even = np.convolve((rep & (idx % 2 == 0)).astype(int), np.ones(2 * half + 1, int), "same")
    odd = np.convolve((rep & (idx % 2 == 1)).astype(int), np.ones(2 * half + 1, int), "same")
    parity = np.where((even >= 3) & (odd <= 1), 0, np.where((odd >= 3) & (even <= 1), 1, -1))
    lead = np.flatnonzero(parity >= 0)
    if len(lead) < 0.5 * T:
        return rep
    j = np.searchsorted(lead, idx)
    after, before = lead[np.minimum(j, len(lead) - 1)], lead[np.maximum(j - 1, 0)]
    nearest = np.where(np.abs(before - idx) < np.abs(after - idx), before, after)
    out = idx % 2 == parity[nearest]
    out[0] = False
    return out


def drop_repeats(images: np.ndarray, t: np.ndarray, *rest: np.ndarray) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, ...], dict]:
    """The captured frames of a clip with repeated frames, evenly spaced in time.

    Args:
        images: ``[T, H, W, 3]`` frames.
        t: ``[T]`` their times, s (increasing).
        rest: other per-frame arrays (``[T, ...]``) kept alongside.

    Returns:
        ``(images, t, rest, info)``: the frames that are not repeats, their times evenly spaced from the first
        kept frame's time to the last's, the other arrays at the same frames, and ``info`` ``{"repeats": n,
        "share": n / T, "fps": the captured rate, Hz}`` (``{"repeats": 0}`` when nothing is dropped). Nothing
        is dropped when the clip has no pattern of repeats or when the captured frames would be spaced
        unevenly (an interval over :data:`MAX_GAP` times their mean: repeats and gaps mixed).
    """
    rep = repeated_frames(images)
    n = int(rep.sum())
    if n == 0:
        return images, t, rest, {"repeats": 0}
    keep = ~rep
    tk = np.asarray(t, np.float64)[keep]
    gaps = np.diff(tk)
    mean = (tk[-1] - tk[0]) / max(len(tk) - 1, 1)
    if len(tk) < 2 or mean <= 0 or float(gaps.max()) > MAX_GAP * mean:
        return images, t, rest, {"repeats": 0, "uneven": n}
    even = tk[0] + mean * np.arange(len(tk))
    return images[keep], even, tuple(r[keep] for r in rest), {"repeats": n, "share": round(n / len(t), 4), "fps": round(1.0 / mean, 4)}
