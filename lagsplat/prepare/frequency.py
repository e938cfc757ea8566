"""The frequency of an object's path, read from its moving part only.

A recording of a mechanical oscillator often holds more than the oscillation:
the object waits before it is released, or dry friction brings it to rest
before the clip ends. Still frames are not a slower oscillation, so the
frequency is read on the span where the object moves (:func:`moving_span`),
along the principal direction of its 2-D path (:func:`principal_path`; a
pendulum bob's vertical coordinate runs at twice the swing frequency), by a
Hann-windowed spectral peak (the paper's estimator), refined on a short path
by counting its crossings of its running mean (:func:`path_frequency`). The share of the path's velocity power that
the peak and its harmonics hold (``peak_share``) tells an oscillation (a clear peak)
from a person shifting in a chair or walking past (power spread over low
frequencies).
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter1d, maximum_filter1d, median_filter, uniform_filter1d

from lagsplat.timeseries import spectral_peak_frequency

__all__ = ["principal_path", "moving_span", "path_frequency", "turning_points", "periods_held", "harmonic_share", "PAD", "MOVING_LEVEL"]

#: Zero-padding factor of the periodogram (a finer grid for the peak; the resolution stays ``1 / duration``).
PAD = 8
#: The peak share counts the fundamental and this many multiples of it (harmonics).
HARMONICS = 3
#: Below this many periods the spectral peak is refined by counting crossings (:func:`_crossing_frequency`).
CROSSING_PERIODS = 5.0
#: A frame moves when its smoothed frame-to-frame change rises this share of the way from the still
#: level (5th percentile) to the moving level (95th percentile).
MOVING_LEVEL = 0.2


def principal_path(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Project a 2-D path on its principal direction.

    Args:
        xy: ``[T, 2]`` positions (px).

    Returns:
        ``(p [T], direction [2])``: the signed coordinate along the direction of largest variance
        (px, about the path's mean) and that unit direction.
    """
    c = xy - xy.mean(0)
    w, v = np.linalg.eigh(c.T @ c)
    d = v[:, int(np.argmax(w))]
    if d[int(np.argmax(np.abs(d)))] < 0:  # a fixed sign: the larger component positive
        d = -d
    return c @ d, d


def moving_span(change: np.ndarray, min_len: int = 8) -> tuple[int, int]:
    """``[start, stop)`` frames over which the object moves.

    Args:
        change: ``[T]`` mean absolute frame-to-frame change over the object's pixels (entry ``t`` is the
            change from frame ``t - 1`` to ``t``; entry 0 is ignored).
        min_len: the shortest span returned; a shorter one (or a clip with no still part) gives the whole clip.

    Returns:
        ``(start, stop)``: the first and one past the last frame whose change, median-filtered and smoothed over 5 frames each, rises
        :data:`MOVING_LEVEL` of the way from the still level to the moving level. A clip whose moving
        level is not twice its still level has no still part: ``(0, T)``.
    """
    T = len(change)
    if T < 3:
        return 0, T
    e = uniform_filter1d(median_filter(np.asarray(change[1:], np.float64), 5, mode="nearest"), 5, mode="nearest")  # no lone spikes (key frames)
    lo, hi = np.percentile(e, 5), np.percentile(e, 95)
    if hi < 2.0 * lo or hi <= 0:
        return 0, T
    on = np.flatnonzero(e > lo + MOVING_LEVEL * (hi - lo))
    if on.size == 0:
        return 0, T
    start, stop = int(on[0]), int(on[-1]) + 2  # e[i] is the change into frame i + 1
    if stop - start < min_len:
        return 0, T
    return start, min(stop, T)


def _crossing_frequency(p: np.ndarray, dt: float, f0: float) -> float:
    """Frequency from the path's crossings of its running mean (one period wide), with hysteresis.

    The path, less its running mean over one period of ``f0`` (which follows a drift of the rest
    position and cancels the oscillation), must pass from below ``-h`` to above ``+h`` (an upward
    crossing) or back, with ``h`` a quarter of the local amplitude (running maximum of ``|y|`` over a
    period), so the noise about a turning point or a stop counts no crossing. The frequency is the
    number of full periods between the first and the last crossing of each direction over the
    time between them (crossing times interpolated between frames), the two directions pooled.

    Returns:
        Hz, or ``nan`` when fewer than two crossings of one direction are found.
    """
    n = len(p)
    w = max(3, int(round(1.0 / (f0 * dt))))
    y = p - uniform_filter1d(p, w, mode="nearest")
    h = 0.25 * maximum_filter1d(np.abs(y), w, mode="nearest")
    periods, spans = 0.0, 0.0
    for sign in (1.0, -1.0):
        z = sign * y
        times, armed = [], False
        for i in range(1, n):
            if z[i] < -h[i]:
                armed = True
            elif armed and z[i] > 0 and z[i - 1] <= 0:
                times.append(i - 1 + (-z[i - 1]) / (z[i] - z[i - 1]))
                armed = False
        if len(times) >= 2:
            periods += len(times) - 1
            spans += (times[-1] - times[0]) * dt
    return periods / spans if spans > 0 else float("nan")


def harmonic_share(power: np.ndarray, freqs: np.ndarray, f0: float, halfwidth: float, harmonics: int | None = None) -> np.ndarray:
    """Share of a periodogram's power in bands about ``f0`` and its multiples, above what a flat spectrum puts there.

    Args:
        power: ``[k, ...]`` power per frequency bin (bin 0 the mean, left out), any trailing axes (several signals).
        freqs: ``[k]`` the bins' frequencies, Hz.
        f0: the fundamental, Hz (> 0).
        halfwidth: each band's half width, Hz.
        harmonics: how many multiples of ``f0`` (the fundamental included); ``None``: all up to the last bin.

    Returns:
        ``[...]`` in [0, 1]: ``(raw - white) / (1 - white)`` with ``raw`` the bands' share of the power and ``white``
        their share of the bins (1 for a periodic signal, about 0 for white noise).
    """
    top = harmonics if harmonics is not None else max(1, int(freqs[-1] / f0))
    near = np.zeros(len(freqs), bool)
    for j in range(1, top + 1):
        near |= np.abs(freqs - j * f0) <= halfwidth
    near[0] = False
    white = float(near[1:].mean())
    raw = power[near].sum(0) / np.maximum(power[1:].sum(0), 1e-300)
    return np.clip((raw - white) / max(1.0 - white, 1e-9), 0.0, 1.0)


def turning_points(p: np.ndarray, share: float = 0.25) -> int:
    """How many times a path turns back: reversals of direction by more than ``share`` of its range (1st to 99th
    percentile), so the noise about a turning point or a stop counts none. A path of ``k`` periods turns about
    ``2 k`` times, whatever the spectrum says of a clip too short to resolve it.
    """
    p = np.asarray(p, np.float64)
    if len(p) < 3:
        return 0
    h = share * float(np.percentile(p, 99) - np.percentile(p, 1))
    if h <= 0:
        return 0
    turns, direction, hi, lo = 0, 0, p[0], p[0]
    for v in p[1:]:
        if direction == 0:  # the first swing's direction, once it is clear
            hi, lo = max(hi, v), min(lo, v)
            if v < hi - h:
                direction, lo = -1, v
            elif v > lo + h:
                direction, hi = 1, v
        elif direction > 0:
            if v > hi:
                hi = v
            elif v < hi - h:
                turns, direction, lo = turns + 1, -1, v
        else:
            if v < lo:
                lo = v
            elif v > lo + h:
                turns, direction, hi = turns + 1, 1, v
    return int(turns)


def periods_held(p: np.ndarray, frequency_hz: float, dt: float) -> float:
    """Periods a path ``p [n]`` (frames ``dt`` s apart) holds at ``frequency_hz``: the spectrum's ``f n dt``, but
    no more than its turning points allow (:func:`turning_points`: a clip too short to resolve its frequency
    shows it in its reversals, ``k`` periods turn about ``2 k`` times); 0 for an unread (non-finite) frequency."""
    if not np.isfinite(frequency_hz):
        return 0.0
    return float(min(frequency_hz * len(p) * dt, (turning_points(p) + 1) / 2.0))


def path_frequency(p: np.ndarray, dt: float) -> tuple[float, float]:
    """Dominant frequency of a 1-D path and how clearly it dominates.

    The paper's spectral estimator (:func:`lagsplat.timeseries.spectral_peak_frequency`: Hann window,
    peak above 1.5 cycles per window, log-parabolic refinement) gives ``f0``; on a path of fewer than
    :data:`CROSSING_PERIODS` periods, whose spectral bins are coarse, it is refined by
    :func:`_crossing_frequency` when that count agrees within 15 % (the crossings time whole periods).
    The peak share is read on the velocity's periodogram, zero-padded :data:`PAD` times.

    Args:
        p: ``[n]`` path (any unit), ``n >= 8``.
        dt: sampling interval, s.

    Returns:
        ``(frequency_hz, peak_share)``: the frequency (``nan`` for a flat path) and the share of the
        velocity's power within two resolution bins (``2 / (n dt)``) of the peak and of its first
        :data:`HARMONICS` multiples, above what a flat spectrum puts there (1 for a periodic motion,
        about 0 for a random walk, whose velocity is white).
    """
    p = np.asarray(p, np.float64)
    n = len(p)
    if n < 8 or not np.isfinite(p).all() or np.ptp(p) <= 0:
        return float("nan"), 0.0
    res = 1.0 / (n * dt)
    freqs = np.fft.rfftfreq(PAD * n, dt)
    window = np.hanning(n)
    try:
        f0 = spectral_peak_frequency(p, dt)
    except ValueError:  # no power above the low-frequency cut
        return float("nan"), 0.0
    # how clearly it oscillates, from the velocity (a step or a slow drift of the path would fill the lowest bins
    # of the position's spectrum): the fundamental's and harmonics' bands against what a flat spectrum puts there
    v = gaussian_filter1d(np.gradient(p), 1.0)
    power = np.abs(np.fft.rfft((v - v.mean()) * window, PAD * n)) ** 2
    share = float(harmonic_share(power, freqs, f0, 2.0 * res, HARMONICS))  # an impact or a large swing: harmonics too
    f = f0
    if f0 * n * dt < CROSSING_PERIODS:  # few periods: the spectrum's bins are coarse, the crossings time whole periods
        fc = _crossing_frequency(p, dt, f0)
        f = fc if np.isfinite(fc) and abs(fc / f0 - 1.0) <= 0.15 else f0
    return float(f), min(1.0, share)
