"""Frame timing: turn the timestamps a file reports into trustworthy ones.

Containers and loggers lie about time in two common ways: a browser recorder
writes a WebM that *claims* 1000 fps while the camera delivered 30, and
per-frame timestamps can jitter by tens of milliseconds although the frames
were captured evenly. Every reader in :mod:`lagsplat.io` therefore funnels its
raw timestamps through :func:`resolve_timing`, which applies one rule:

Definitions (``dt`` = consecutive timestamp intervals of *all* decoded frames):

* the container's frame rate is **absurd** if it is missing, not finite,
  ``< 1`` fps (so also ``<= 0``) or ``> max_fps`` (default 240);
* the timestamps **jitter** if any interval is ``<= 0`` or
  ``std(dt) / mean(dt) > jitter_tol`` (default 0.05).

Rule, first match wins:

1. ``fps`` given (the true capture rate, ``system.source.fps``): uniform
   timestamps ``t_i = i / fps`` (rule ``"config_fps"``). A
   :class:`TimingWarning` naming the file is issued if the container's fps is
   absurd, if the timestamps jitter, or if the timestamps' mean rate
   ``(T-1) / (t_last - t_first)`` differs from ``fps`` by more than 1 %.
2. Timestamps regular (no jitter) and spanning ``> 0`` s: use them, shifted to
   start at 0 (rule ``"timestamps"``), even if the container's nominal fps
   differs slightly (a ``.mov`` saying 59.77 fps whose frames are exactly
   1001/60000 s apart gets the timestamps).
3. Timestamps jitter but the container's fps is plausible: warn and use
   uniform timestamps at the timestamps' mean rate (rule ``"mean_rate"``); if
   the timestamps do not span any time at all, fall back to the container's
   fps (rule ``"container_fps"``, also warned).
4. Otherwise (container fps absurd or absent, timestamps jitter, no ``fps``):
   raise :class:`~lagsplat.io.clip.ClipError` with one line naming the file,
   e.g. ``oscillating_cart.webm: container claims 1000 fps and frame
   timestamps jitter (31-49 ms); state the true capture rate with
   system.source.fps=<Hz>``.

A single frame gets ``t = [0]`` (rule ``"single_frame"``).
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from lagsplat.io.clip import ClipError

__all__ = ["TimingWarning", "resolve_timing", "is_absurd_fps", "timestamp_jitter"]


class TimingWarning(UserWarning):
    """Issued when a file's timing is doubtful and a fallback was applied."""


def is_absurd_fps(fps: float | None, max_fps: float = 240.0) -> bool:
    """Return True if a container frame rate cannot be a real capture rate.

    Args:
        fps: frame rate in Hz reported by a container, or None if it reports none.
        max_fps: largest plausible capture rate in Hz.
    """
    if fps is None:
        return True
    try:
        f = float(fps)
    except (TypeError, ValueError):
        return True
    return not math.isfinite(f) or f < 1.0 or f > max_fps


def timestamp_jitter(raw_t: np.ndarray, jitter_tol: float = 0.05) -> bool:
    """Return True if timestamps (seconds, ``[T]``) are irregular.

    Irregular means some interval is ``<= 0`` or the coefficient of variation
    ``std(dt) / mean(dt)`` exceeds ``jitter_tol``. Fewer than 2 timestamps
    never jitter.
    """
    raw_t = np.asarray(raw_t, dtype=np.float64)
    if raw_t.size < 2:
        return False
    dt = np.diff(raw_t)
    if not np.all(np.isfinite(dt)) or np.any(dt <= 0):
        return True
    return bool(np.std(dt) / np.mean(dt) > jitter_tol)


def _fmt_fps(fps: float | None) -> str:
    if fps is None:
        return "no"
    f = float(fps)
    if not math.isfinite(f):
        return f"{f}"
    return f"{f:g}"


def _fmt_range_ms(dt_ms: np.ndarray) -> str:
    lo, hi = float(np.min(dt_ms)), float(np.max(dt_ms))
    if lo > 0:
        return f"{lo:.0f}-{hi:.0f} ms"
    return f"{lo:.0f} to {hi:.0f} ms, not increasing"


def resolve_timing(
    raw_t: np.ndarray,
    source: str | Path,
    *,
    fps: float | None = None,
    container_fps: float | None = None,
    has_container: bool = True,
    max_fps: float = 240.0,
    jitter_tol: float = 0.05,
) -> tuple[np.ndarray, dict[str, Any]]:
    """Apply the module's timing rule to the raw timestamps of a file.

    Args:
        raw_t: float ``[T]`` raw timestamps in seconds of every decoded frame,
            in decode order (any origin).
        source: file name used in warnings and errors.
        fps: true capture rate in Hz from the configuration, or None.
        container_fps: frame rate in Hz the container states (None if none).
        has_container: False for sources without a nominal frame rate at all
            (e.g. MCAP); then the container fps plays no part and is never
            warned about.
        max_fps: largest plausible container frame rate in Hz.
        jitter_tol: tolerated ``std(dt) / mean(dt)``.

    Returns:
        ``(t, info)``: ``t`` float64 ``[T]`` seconds starting at 0, strictly
        increasing; ``info`` a JSON-serialisable dict with ``container_fps``,
        ``rule`` (``"config_fps" | "timestamps" | "mean_rate" |
        "container_fps" | "single_frame"``), ``dt_ms_min``, ``dt_ms_median``,
        ``dt_ms_max`` (raw intervals, None for a single frame),
        ``timestamp_rate_hz``, ``jitter``, ``fps`` (rate of the returned
        ``t``) and ``warnings`` (messages issued).

    Raises:
        ClipError: if ``fps`` is not a positive finite number, or if no rule
            applies (absurd container fps and jittering timestamps).

    Warns:
        TimingWarning: for every doubt listed in the module docstring.
    """
    src = str(source)
    raw_t = np.asarray(raw_t, dtype=np.float64).reshape(-1)
    T = raw_t.size
    if T == 0:
        raise ClipError(f"{src}: no frames to time")
    cfps = None if container_fps is None else float(container_fps)
    absurd = is_absurd_fps(cfps, max_fps) if has_container else True
    dt_ms = np.diff(raw_t) * 1e3
    jitter = timestamp_jitter(raw_t, jitter_tol)
    span = float(raw_t[-1] - raw_t[0]) if T > 1 else 0.0
    rate = (T - 1) / span if span > 0 and math.isfinite(span) else None
    info: dict[str, Any] = {
        "container_fps": cfps if (cfps is None or math.isfinite(cfps)) else None,
        "container_fps_absurd": bool(absurd) if has_container else None,
        "rule": None,
        "dt_ms_min": float(dt_ms.min()) if T > 1 else None,
        "dt_ms_median": float(np.median(dt_ms)) if T > 1 else None,
        "dt_ms_max": float(dt_ms.max()) if T > 1 else None,
        "timestamp_rate_hz": rate,
        "jitter": bool(jitter),
        "jitter_tol": float(jitter_tol),
        "max_fps": float(max_fps),
        "fps": None,
        "warnings": [],
    }

    def warn(msg: str) -> None:
        info["warnings"].append(msg)
        warnings.warn(msg, TimingWarning, stacklevel=4)

    if fps is not None:
        try:
            f = float(fps)
        except (TypeError, ValueError):
            f = float("nan")
        if not math.isfinite(f) or f <= 0:
            raise ClipError(f"{src}: system.source.fps must be a positive number of frames per second, got {fps!r}")
        info["rule"] = "config_fps"
        info["fps"] = f
        if has_container and absurd:
            warn(f"{src}: container claims {_fmt_fps(cfps)} fps; using the configured {f:g} fps")
        if jitter:
            warn(f"{src}: frame timestamps jitter ({_fmt_range_ms(dt_ms)}); using uniform timestamps at the configured {f:g} fps")
        if rate is not None and abs(rate / f - 1.0) > 0.01:
            warn(
                f"{src}: frame timestamps run at {rate:.4g} fps on average but system.source.fps={f:g}; "
                f"using the configured rate"
            )
        return np.arange(T, dtype=np.float64) / f, info

    if T == 1:
        info["rule"] = "single_frame"
        return np.zeros(1, np.float64), info

    if not jitter and rate is not None:
        info["rule"] = "timestamps"
        info["fps"] = rate
        return raw_t - raw_t[0], info

    if has_container and not absurd:
        if rate is not None:
            info["rule"] = "mean_rate"
            info["fps"] = rate
            warn(
                f"{src}: frame timestamps jitter ({_fmt_range_ms(dt_ms)}); using uniform timestamps at their "
                f"mean rate {rate:.4g} fps (container says {_fmt_fps(cfps)} fps); "
                f"state the true capture rate with system.source.fps=<Hz>"
            )
            return np.arange(T, dtype=np.float64) / rate, info
        info["rule"] = "container_fps"
        info["fps"] = cfps
        warn(
            f"{src}: frame timestamps do not advance; using uniform timestamps at the container's "
            f"{_fmt_fps(cfps)} fps; state the true capture rate with system.source.fps=<Hz>"
        )
        return np.arange(T, dtype=np.float64) / cfps, info

    what = f"container claims {_fmt_fps(cfps)} fps" if has_container else "the file states no frame rate"
    raise ClipError(
        f"{src}: {what} and frame timestamps jitter ({_fmt_range_ms(dt_ms)}); "
        f"state the true capture rate with system.source.fps=<Hz>"
    )
