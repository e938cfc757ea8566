"""Chamber pressures driving the simulated robot: band-limited random schedules with rest intervals (:class:`PressureSchedule`).

Part of :mod:`lagsplat.synth.continuum_robot` (its docstring describes the model).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lagsplat.synth.continuum_robot.constants import (
    DEFAULT_DURATION_S,
    PRESSURE_BAND_HZ,
)
from lagsplat.synth.continuum_robot.model import check_positive, check_segments


def _raised_cosine(x: np.ndarray) -> np.ndarray:
    """0 for x <= 0, 1 for x >= 1, ``(1 - cos(pi x)) / 2`` between (C1-smooth step)."""
    xc = np.clip(x, 0.0, 1.0)
    return 0.5 * (1.0 - np.cos(math.pi * xc))


@dataclass(frozen=True)
class PressureSchedule:
    """Chamber pressures ``p_c(t) = g(t) p_max (1 + s_c(t) / max|s_c|) / 2`` (module docstring).

    Build it with :meth:`random`. All times in seconds.

    Attributes:
        n_chambers: ``2 n_segments``.
        duration_s: clip length.
        freqs_hz, phases, amplitudes: float64 ``[n_chambers, n_components]``
            of the sinusoids of ``s_c``.
        scale: float64 ``[n_chambers]``, ``max|s_c|`` over the clip.
        p_max: largest pressure (normalised by 101 325 Pa).
        head_s: end of the static head (start of the first ramp).
        ramp_s, release_s: durations of the ramps up and of the releases.
        rests: ``(t_release_start, t_ramp_start)`` of each mid-clip zero-pressure interval.
        tail_release_s: start of the final release; ``g = 0`` from ``tail_release_s + release_s`` on.
        params: the arguments of :meth:`random`.
    """

    n_chambers: int
    duration_s: float
    freqs_hz: np.ndarray
    phases: np.ndarray
    amplitudes: np.ndarray
    scale: np.ndarray
    p_max: float
    head_s: float
    ramp_s: float
    release_s: float
    rests: tuple[tuple[float, float], ...]
    tail_release_s: float
    params: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def random(
        cls,
        n_segments: int,
        duration_s: float = DEFAULT_DURATION_S,
        seed: int = 0,
        *,
        p_max: float = 0.9,
        band_hz: Sequence[float] = PRESSURE_BAND_HZ,
        n_components: int = 48,
        spectral_slope: float = 0.5,
        head_s: float | None = None,
        tail_s: float | None = None,
        rest_s: float | None = None,
        n_rest: int = 2,
        ramp_s: float = 2.0,
        release_s: float = 0.05,
        train_fraction: float = 0.8,
    ) -> PressureSchedule:
        """A seeded random schedule: static head, band-limited drive with rest intervals, depressurised tail.

        Args:
            n_segments: 1 or 2 (two chambers per segment).
            duration_s: clip length (s).
            seed: seeds every random draw (``np.random.default_rng(seed)``).
            p_max: largest pressure, normalised by 101 325 Pa (0 < p_max <= 2).
            band_hz: ``(f_lo, f_hi)`` band of the sinusoids (Hz), ``0 < f_lo < f_hi``.
            n_components: sinusoids per chamber (>= 1).
            spectral_slope: amplitudes scale as ``f^-spectral_slope`` (>= 0; 0 = flat).
            head_s: static head (s); default ``min(8, 0.06 duration_s)``.
            tail_s: depressurised tail (s); default ``min(20, 0.15 duration_s)``.
            rest_s: length of each mid-clip zero-pressure interval (s);
                default ``min(8, 0.06 duration_s)``.
            n_rest: number of such intervals, all inside the first
                ``train_fraction`` of the clip (>= 0).
            ramp_s: raised-cosine ramp from 0 to full drive (s).
            release_s: raised-cosine depressurisation (s), short so the robot rings.
            train_fraction: the consumer's contiguous training share (the
                tail must lie after it, the rests before it), in (0, 1).

        Returns:
            The :class:`PressureSchedule`.

        Raises:
            ValueError: on invalid arguments, or if the head, rests and tail do
                not fit (the tail must start after ``train_fraction *
                duration_s`` and at least one ramp of drive must remain
                between consecutive events); the message says which.
        """
        n_ch = 2 * check_segments(n_segments)
        dur = check_positive(duration_s, "duration_s")
        pm = check_positive(p_max, "p_max")
        if pm > 2.0:
            raise ValueError(f"p_max is a pressure divided by 101325 Pa and must be <= 2, got {p_max!r}")
        try:
            f_lo, f_hi = (float(v) for v in band_hz)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"band_hz must be (f_lo, f_hi), got {band_hz!r}") from exc
        if not (0.0 < f_lo < f_hi and math.isfinite(f_hi)):
            raise ValueError(f"band_hz must satisfy 0 < f_lo < f_hi, got {band_hz!r}")
        if isinstance(n_components, bool) or int(n_components) != n_components or int(n_components) < 1:
            raise ValueError(f"n_components must be an integer >= 1, got {n_components!r}")
        slope = check_positive(spectral_slope, "spectral_slope", allow_zero=True)
        if isinstance(n_rest, bool) or int(n_rest) != n_rest or int(n_rest) < 0:
            raise ValueError(f"n_rest must be an integer >= 0, got {n_rest!r}")
        tf = float(train_fraction)
        if not (0.0 < tf < 1.0):
            raise ValueError(f"train_fraction must be in (0, 1), got {train_fraction!r}")
        head = min(8.0, 0.06 * dur) if head_s is None else check_positive(head_s, "head_s", allow_zero=True)
        tail = min(20.0, 0.15 * dur) if tail_s is None else check_positive(tail_s, "tail_s")
        rest = min(8.0, 0.06 * dur) if rest_s is None else check_positive(rest_s, "rest_s")
        ramp = check_positive(ramp_s, "ramp_s")
        rel = check_positive(release_s, "release_s")

        tail_release = dur - tail - rel
        if tail_release < tf * dur - 1e-9:
            raise ValueError(
                f"the depressurised tail ({tail:g} s + {rel:g} s release) must start after the training share "
                f"({tf:g} x {dur:g} s = {tf * dur:g} s); shorten tail_s or lengthen duration_s"
            )
        drive0 = head + ramp  # full drive from here
        if tail_release < drive0 + ramp:
            raise ValueError(
                f"duration_s = {dur:g} s leaves no drive between the head ({head:g} s + {ramp:g} s ramp) and the tail "
                f"({tail:g} s); lengthen duration_s or shorten head_s / tail_s"
            )
        rng = np.random.default_rng(int(seed))
        rests: list[tuple[float, float]] = []
        n_r = int(n_rest)
        if n_r:
            block = rel + rest + ramp  # release, zero, ramp back
            lo, hi = drive0 + ramp, tf * dur  # a ramp of drive before each rest and after it, all in training
            slot = (hi - lo) / n_r
            if slot < block + ramp:
                raise ValueError(
                    f"{n_r} rest interval(s) of {rest:g} s do not fit in the training share after the head "
                    f"({lo:g}..{tf * dur:g} s); use fewer (n_rest), shorter (rest_s) or a longer duration_s"
                )
            for k in range(n_r):
                # Anywhere in the slot that leaves a ramp of drive before the next one.
                start = lo + k * slot + rng.uniform(0.0, slot - block - ramp)
                rests.append((start, start + rel + rest))

        freqs = rng.uniform(f_lo, f_hi, (n_ch, int(n_components)))
        phases = rng.uniform(0.0, 2.0 * math.pi, (n_ch, int(n_components)))
        amps = rng.rayleigh(1.0, (n_ch, int(n_components))) * (freqs / f_lo) ** (-slope)
        sched = cls(
            n_chambers=n_ch,
            duration_s=dur,
            freqs_hz=freqs,
            phases=phases,
            amplitudes=amps,
            scale=np.ones(n_ch),
            p_max=pm,
            head_s=head,
            ramp_s=ramp,
            release_s=rel,
            rests=tuple(rests),
            tail_release_s=tail_release,
            params={
                "p_max": pm,
                "band_hz": [f_lo, f_hi],
                "n_components": int(n_components),
                "spectral_slope": slope,
                "head_s": head,
                "tail_s": tail,
                "rest_s": rest,
                "n_rest": n_r,
                "ramp_s": ramp,
                "release_s": rel,
                "train_fraction": tf,
            },
        )
        # max|s_c| on a grid fine enough for the band (>= 40 samples per shortest period).
        t_fine = np.linspace(0.0, dur, math.ceil(dur * f_hi * 40) + 2)
        scale = np.max(np.abs(sched.carrier(t_fine)), axis=0) * 1.01  # margin: the grid can miss the true peak
        object.__setattr__(sched, "scale", scale)
        return sched

    def carrier(self, t: Any) -> np.ndarray:
        """``s_c(t)`` float64 ``[len(t), n_chambers]`` (before normalisation), sum of in-band sinusoids."""
        tt = np.atleast_1d(np.asarray(t, dtype=np.float64))
        out = np.empty((tt.shape[0], self.n_chambers))
        for c in range(self.n_chambers):
            for a in range(0, tt.shape[0], 4096):
                arg = 2.0 * math.pi * tt[a:a + 4096, None] * self.freqs_hz[c] + self.phases[c]
                out[a:a + 4096, c] = np.cos(arg) @ self.amplitudes[c]
        return out

    def gate(self, t: Any) -> np.ndarray:
        """``g(t)`` float64 ``[len(t)]`` in [0, 1]: head, ramps, releases, rests, tail."""
        tt = np.atleast_1d(np.asarray(t, dtype=np.float64))
        g = _raised_cosine((tt - self.head_s) / self.ramp_s)
        for t_rel, t_up in self.rests:
            g = g * (1.0 - _raised_cosine((tt - t_rel) / self.release_s) + _raised_cosine((tt - t_up) / self.ramp_s))
        g = g * (1.0 - _raised_cosine((tt - self.tail_release_s) / self.release_s))
        return np.clip(g, 0.0, 1.0)

    def __call__(self, t: Any) -> np.ndarray:
        """Pressures float64 ``[len(t), n_chambers]`` in ``[0, p_max]`` at times ``t`` (s)."""
        tt = np.atleast_1d(np.asarray(t, dtype=np.float64))
        p = 0.5 * self.p_max * (1.0 + self.carrier(tt) / self.scale)
        p = p * self.gate(tt)[:, None]
        return np.clip(p, 0.0, self.p_max)

    @property
    def tail_start_s(self) -> float:
        """First time with zero pressure for good (end of the final release)."""
        return self.tail_release_s + self.release_s


