"""Where a periodic force or a hidden mode is sought: the residual's spectral peaks and the bands left out.

Used by the ``periodic_force`` and ``missing_dof`` candidates of
:mod:`lagsplat.diagnose.effects` (their frequency grid) and by the spectrum
evidence of :mod:`lagsplat.diagnose.signatures`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from lagsplat.diagnose.residual_data import Residual

__all__ = ["residual_peaks", "reference_frequencies", "excluded_bands", "frequency_allowed", "longest_segment_s"]


def longest_segment_s(res: Residual) -> float:
    """Duration of the residual's longest segment, s (what a frequency is resolved against)."""
    return max(len(st.t) for st in res.states) * res.dt


def reference_frequencies(res: Residual, model_freqs_hz: Sequence[float] | None = None) -> list[float]:
    """The frequencies the model already has, Hz, sorted: its modes (``model_freqs_hz``; default
    ``res.meta["model_freqs_hz"]``) and the encoded motion's dominant frequency, finite and positive."""
    modes = res.meta.get("model_freqs_hz", []) if model_freqs_hz is None else model_freqs_hz
    return sorted({float(f) for f in [*modes, res.f_dominant_hz] if math.isfinite(f) and f > 0})


def excluded_bands(res: Residual, model_freqs_hz: Sequence[float] | None = None) -> tuple[tuple[float, float], ...]:
    """``(frequency, relative half-width)`` bands where a periodic force or hidden mode is not sought.

    The model's own modes (``model_freqs_hz``, Hz; default ``res.meta["model_freqs_hz"]``) and the dominant
    frequency of the encoded motion itself (+-10 %), their harmonics and, with
    several modes, their sum and difference frequencies (+-12 % of the mode
    frequency): a residual there is a misfit or a distortion (a nonlinear chart
    or force) of the motion the model has, not a force or a mode it lacks (and a
    force locked to a harmonic could not be told from one); and the logged
    inputs' strongest frequencies (+-10 %), where an unlogged force cannot be
    told from an input-gain error. Around the modes and the motion's frequency
    the band is at least ``1.5 / T`` wide on each side (``T`` the longest
    segment; the same 1.5 cycles per record as the searchable band's lower
    edge, :func:`frequency_allowed`): a force closer beats with the oscillation
    fewer than 1.5 times over the record, and that slow modulation cannot be
    told from a drift of the oscillation or from a model whose frequency follows
    the decaying amplitude a little differently (on a realistic pendulum with
    dry friction, a "force" just below the oscillation's frequency was such a
    misfit). The observed frequency counts besides the
    model's linearised ones because a chart distortion puts its harmonics at
    multiples of the motion *as recorded*: on a control clip of the blind suite,
    whose motion ran a little slower than the model's mode, the 2nd harmonic of the
    motion sat just outside the band around twice the model's mode and was taken
    for a hidden mode (the measurements: ``docs/experiments/code_comment_history.md``).
    """
    base = reference_frequencies(res, model_freqs_hz)
    f_max = 0.25 / res.dt
    # harmonics k f (k >= 2) up to the band edge, each +-0.12 f: a distorted chart or force puts power there
    T = longest_segment_s(res)
    out = [(f, max(0.1, 1.5 / (T * f))) for f in base] + [(k * f, 0.12 / k) for f in base for k in range(2, int(f_max / f) + 2)]
    out += [(g, 0.12 * min(f, h) / g) for i, f in enumerate(base) for h in base[i + 1 :] for g in (f + h, abs(f - h)) if g > 0]  # combination tones
    for j in range(res.n_u):
        out += [(f, 0.1) for f in residual_peaks(res.u[:, j], res.segment, res.dt, 3)]
    return tuple(out)


def frequency_allowed(res: Residual, f: float, model_freqs_hz: Sequence[float] | None = None) -> bool:
    """Whether a periodic force / hidden mode at ``f`` Hz may be sought: inside the searchable band, outside :func:`excluded_bands`.

    The searchable band runs from 1.5 cycles of the longest segment to a quarter of the sampling rate.
    ``model_freqs_hz``: the model's modes (Hz; default ``res.meta["model_freqs_hz"]``).
    """
    T = longest_segment_s(res)
    if not (1.5 / T <= f <= 0.25 / res.dt):
        return False
    return all(abs(f - g) > rel * g for g, rel in excluded_bands(res, model_freqs_hz) if math.isfinite(g) and g > 0)


def residual_peaks(
    x: np.ndarray, seg: np.ndarray, dt: float, n_peaks: int = 3, f_min: float | None = None, f_max: float | None = None,
    exclude: tuple[tuple[float, float], ...] = (),
) -> list[float]:
    """Frequencies (Hz) of the strongest peaks of a residual's power spectrum.

    The Hann-windowed periodogram of each segment (zero-padded to a common
    grid of ``1 / (4 T_max)`` Hz), summed over segments (incoherently);
    local maxima by :func:`scipy.signal.find_peaks`, strongest first.

    Args:
        x: ``[n]`` residual (one coordinate).
        seg: ``[n]`` segment index of each sample.
        dt: sampling interval, s.
        n_peaks: number of peaks returned (at most).
        f_min, f_max: band searched, Hz (default: 1.5 cycles of the longest segment
            to a quarter of the sampling rate).
        exclude: ``(frequency, relative half-width)`` bands skipped (see :func:`excluded_bands`).

    Returns:
        Up to ``n_peaks`` frequencies, Hz.
    """
    from scipy.signal import find_peaks

    parts = [x[seg == k] for k in np.unique(seg)]
    parts = [p - p.mean() for p in parts if len(p) >= 8]
    if not parts:
        return []
    L = max(len(p) for p in parts)
    nfft = 1 << int(math.ceil(math.log2(4 * L)))
    f = np.fft.rfftfreq(nfft, dt)
    P = sum(np.abs(np.fft.rfft(p * np.hanning(len(p)), nfft)) ** 2 for p in parts)
    lo = 1.5 / (L * dt) if f_min is None else f_min
    hi = 0.25 / dt if f_max is None else f_max
    band = (f >= lo) & (f <= hi)
    for f_x, rel in exclude:
        if math.isfinite(f_x) and f_x > 0:
            band &= np.abs(f - f_x) > rel * f_x
    if not band.any():
        return []
    Pb = np.where(band, P, 0.0)
    idx, _ = find_peaks(Pb)
    idx = idx[np.argsort(Pb[idx])[::-1]][:n_peaks]
    return [float(f[i]) for i in idx]

