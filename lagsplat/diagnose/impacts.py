"""Impacts read off the chart: the motion reversed at a nearly fixed position, and the restitution.

A rigid stop met on every swing (a bumper, a door stop, a pendulum striking a wall) reverses
the velocity within a frame: the object arrives at speed ``v-`` and leaves at ``e v-``, ``e``
the coefficient of restitution (Newton's law of restitution; Stronge, *Impact Mechanics*,
2000, ch. 1). A smooth turning point (a spring, a cubic stiffness) brings the speed to zero
first. :func:`impact_signature` reads, at every turning point of the chart's own positions
along a direction, two arcs of one harmonic motion that meet at a sub-frame apex
(:func:`reversal_fit`): their slopes at the apex are the speeds before and after the
reversal. A turning point is an *impact* when the object arrives there at a sizeable share
of its peak speed (:data:`MIN_ARRIVAL_SHARE`); a side of the motion *has a stop* when most of
its turning points up to its last impact are impacts (:data:`MIN_IMPACT_SHARE`, at least
:data:`MIN_IMPACTS`; a low restitution takes the energy out in a few impacts, and the swings
that follow fall short of the stop), at a position that stays put (their spread). The restitution is the median speed ratio across the
impacts, with a 90 % interval from a bootstrap of that median over the impacts. The
evidence that the reversals are impacts, on the ``Delta BIC`` scale: at each impact, the
reversal fit against one smooth arc through the same samples (a Gaussian likelihood ratio,
two parameters more: the slope's jump and the apex), summed over the impacts.

The ratio of two speeds at one position does not depend on the chart's scale there (a
smooth, monotone reparametrisation scales both by the same factor), so it reads the
restitution in any chart coordinate.
"""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np
from scipy.signal import find_peaks

__all__ = ["reversal_fit", "impact_signature", "MIN_ARRIVAL_SHARE", "MIN_IMPACT_SHARE", "MIN_IMPACTS"]

#: A turning point is an impact when the object arrives at it at least this share of its peak speed.
MIN_ARRIVAL_SHARE = 0.25
#: A side has a stop when at least this share of its turning points are impacts ...
MIN_IMPACT_SHARE = 0.6
#: ... and at least this many (two: a restitution of 0.5 leaves a quarter of the energy after one impact, and the
#: swings that follow may fall short of the stop; on the smooth oscillators of the tests and of the latent suites no
#: side shows two).
MIN_IMPACTS = 2
#: A turning point stands out of the motion's 5-95 % range by at least this share of it (not a noise wiggle).
PROMINENCE = 0.2
#: The reversal fit reaches this fraction of a period to either side of a turning point (at least 3 frames).
HALF_DIV = 5.0
#: The arcs of the reversal fit turn at this share of the observed angular frequency (a stop met on every swing
#: shortens the period: the free spring's frequency lies below the observed one).
OMEGA_SHARE = 0.8
#: Bootstrap draws of the restitution's interval (fixed seed).
N_BOOT = 2000


def _arc(u: np.ndarray, omega: float) -> tuple[np.ndarray, np.ndarray]:
    """The two shapes of an arc at offsets ``u`` (frames) from its apex: ``(slope, curve)``, the terms a speed and an
    acceleration there multiply; harmonic (``sin(omega u) / omega``, ``cos(omega u) - 1``) for ``omega > 0``,
    else the parabola's (``u``, ``u^2``)."""
    if omega > 0:  # the linear oscillator's own motion: c + a (cos(w u) - 1) + (v / w) sin(w u)
        return np.sin(omega * u) / omega, np.cos(omega * u) - 1.0
    return u, u * u


def reversal_fit(p: np.ndarray, half: int, omega: float = 0.0) -> tuple[float, float, float, float, float]:
    """Two parabolas meeting at an apex near the middle of ``p``, one on each side of it, with one curvature.

    Either side of an impact the object is at the same place, so the smooth law gives it the
    same acceleration just before and just after (the damping's share aside): the two parabolas
    share their second-order term, and only the slope jumps at the apex.

    With ``omega > 0`` (rad per frame) the two sides are arcs of one harmonic motion instead,
    ``c + a (cos(omega u) - 1) + (v / omega) sin(omega u)``, ``v`` jumping at the apex: the exact
    motion of a linear spring either side of an impact, which a parabola bends away from within
    a fifth of a period.

    Args:
        p: ``[2 half + 1]`` positions around a turning point (the middle sample), one per frame.
        half: samples on either side of the middle.
        omega: the motion's angular frequency, rad per frame (0: parabolas).

    Returns:
        ``(tau, s0, v_before, v_after, ssr)``: the apex's offset from the middle sample (frames, in
        ``[-1, 1]``), its position, the slopes (position per frame) of the two sides at it, and the
        sum of squared residuals.

    Raises:
        ValueError: if ``p`` does not hold ``2 half + 1`` samples or ``half < 3``.
    """
    if half < 3 or len(p) != 2 * half + 1:
        raise ValueError(f"need 2 half + 1 samples with half >= 3, got {len(p)} with half {half}")
    t = np.arange(-half, half + 1, dtype=np.float64)
    best = None
    for tau in np.linspace(-1.0, 1.0, 41):
        u = t - tau
        before = u < 0
        slope, curve = _arc(u, omega)
        A = np.stack([np.ones_like(u), slope * before, slope * ~before, curve], 1)
        coef, *_ = np.linalg.lstsq(A, p, rcond=None)
        ssr = float(np.sum((A @ coef - p) ** 2))
        if best is None or ssr < best[0]:
            best = (ssr, float(tau), coef)
    ssr, tau, c = best
    return tau, float(c[0]), float(c[1]), float(c[2]), ssr


def _smooth_ssr(p: np.ndarray, half: int, omega: float) -> float:
    """Sum of squared residuals of one smooth arc through ``p`` (:func:`reversal_fit` without the slope's jump)."""
    u = np.arange(-half, half + 1, dtype=np.float64)
    A = np.stack([np.ones_like(u), *_arc(u, omega)], 1)
    coef, *_ = np.linalg.lstsq(A, p, rcond=None)
    return float(np.sum((A @ coef - p) ** 2))


def _side(p: np.ndarray, peaks: np.ndarray, sgn: float, half: int, v_peak: float, omega: float) -> list[dict[str, float]]:
    """The reversal fit at each turning point of one side (``sgn`` +1: maxima, -1: minima)."""
    out = []
    for i in peaks:
        if half <= i < len(p) - half:
            w = p[i - half : i + half + 1]
            tau, s0, v1, v2, ssr = reversal_fit(w, half, omega)
            arriving = sgn * v1  # > 0: moving towards the side's extreme
            leaving = -sgn * v2  # > 0: moving back
            n = len(w)
            gain = n * math.log(max(_smooth_ssr(w, half, omega), 1e-300) / max(ssr, 1e-300)) - 2.0 * math.log(n)
            out.append({"i": float(i + tau), "s": s0, "arrive": arriving, "leave": leaving, "evidence": float(gain),
                        "impact": bool(arriving >= MIN_ARRIVAL_SHARE * v_peak and leaving > 0)})  # fmt: skip
    return out


def _median_interval(x: np.ndarray, rng: np.random.Generator) -> list[float]:
    """90 % bootstrap interval ``[lo, hi]`` of the median of ``x`` (:data:`N_BOOT` draws); ``nan`` for fewer than 2 values."""
    if len(x) < 2:
        return [float("nan")] * 2
    boot = np.median(rng.choice(x, size=(N_BOOT, len(x))), axis=1)
    return [float(np.percentile(boot, 5)), float(np.percentile(boot, 95))]


def impact_signature(s: np.ndarray, segments: Sequence[np.ndarray], dt: float, f_hz: float, seed: int = 0) -> dict[str, Any]:
    """Impacts on either side of a 1-D motion (module docstring).

    Args:
        s: ``[T]`` positions along one direction of the chart (its own, unsmoothed positions).
        segments: index arrays of the contiguous recordings in ``s``.
        dt: frame interval, s.
        f_hz: the motion's dominant frequency, Hz (turning points at least 0.35 periods apart; the fit
            window is ``1 / HALF_DIV`` of a period on either side, at least 3 frames).
        seed: the bootstrap's seed.

    Returns:
        ``{"upper": side, "lower": side, "stop_side": "upper" | "lower" | None}``, each ``side``
        ``{"n_turning_points", "n_while_met", "n_impacts", "s_stop", "s_stop_spread", "arrival_share" (median arrival speed over
        the peak speed), "restitution", "restitution_90" ([lo, hi]), "impact_frames", "evidence"}`` (``restitution`` ``nan``
        without impacts, ``ratios`` the speed ratio of each impact); ``stop_side`` the side whose turning points are
        impacts (:data:`MIN_IMPACT_SHARE`, :data:`MIN_IMPACTS`), the one with more impacts when both are;
        ``both_sides`` where both sides strike a stop (with a stop on each side the energy goes twice a cycle, and
        each side sees few impacts): ``{"restitution", "restitution_90", "n_impacts", "evidence"}`` over the impacts
        of both, else ``None``.
    """
    if not (math.isfinite(f_hz) and f_hz > 0 and dt > 0):
        return {"upper": {}, "lower": {}, "stop_side": None, "both_sides": None}
    period = 1.0 / (f_hz * dt)  # frames
    gap, half = max(1, int(0.35 * period)), max(3, int(round(period / HALF_DIV)))
    sides: dict[str, list[dict[str, float]]] = {"upper": [], "lower": []}
    for idx in segments:
        p = np.asarray(s[idx], np.float64)
        if len(p) < 2 * half + 1:
            continue
        v = np.abs(np.diff(p))
        v_peak = float(np.percentile(v, 95)) if len(v) else 0.0
        if v_peak <= 0:
            continue
        prom = PROMINENCE * float(np.subtract(*np.percentile(p, [95, 5])))
        for name, sgn in (("upper", 1.0), ("lower", -1.0)):
            peaks = find_peaks(sgn * p, distance=gap, prominence=prom)[0]
            for r in _side(p, peaks, sgn, half, v_peak, OMEGA_SHARE * 2 * math.pi / period):
                r["i"] += float(idx[0])
                r["arrival_share"] = r["arrive"] / v_peak
                sides[name].append(r)
    rng = np.random.default_rng(seed)
    out: dict[str, Any] = {}
    for name, rows in sides.items():
        imp = [r for r in rows if r["impact"]]
        last = max((r["i"] for r in imp), default=-math.inf)
        met = [r for r in rows if r["i"] <= last]  # the turning points while the stop is met (a low restitution ends the impacts)
        ratio = np.array([r["leave"] / r["arrive"] for r in imp])
        pos = np.array([r["s"] for r in imp])
        out[name] = {
            "n_turning_points": len(rows), "n_while_met": len(met), "n_impacts": len(imp),
            "s_stop": float(np.median(pos)) if len(pos) else float("nan"),
            "s_stop_spread": float(np.subtract(*np.percentile(pos, [75, 25]))) if len(pos) >= 2 else float("nan"),
            "arrival_share": float(np.median([r["arrival_share"] for r in rows])) if rows else float("nan"),
            "restitution": float(np.median(ratio)) if len(ratio) else float("nan"), "restitution_90": _median_interval(ratio, rng),
            "impact_frames": [round(r["i"], 2) for r in imp], "ratios": ratio.round(4).tolist(),
            "evidence": float(sum(r["evidence"] for r in imp)),
        }  # fmt: skip
    share_ok = {n: out[n]["n_impacts"] >= MIN_IMPACT_SHARE * out[n]["n_while_met"] for n in ("upper", "lower")}
    has = [n for n in ("upper", "lower") if out[n]["n_impacts"] >= MIN_IMPACTS and share_ok[n]]
    # stops on both sides: the energy goes twice per cycle, so each side sees few impacts; one restitution over all
    if len(has) == 2:
        pooled = np.array(out["upper"]["ratios"] + out["lower"]["ratios"])
        out["both_sides"] = {"restitution": float(np.median(pooled)), "restitution_90": _median_interval(pooled, rng),
                             "n_impacts": len(pooled), "evidence": out["upper"]["evidence"] + out["lower"]["evidence"]}  # fmt: skip
    else:
        out["both_sides"] = None
    out["stop_side"] = max(has, key=lambda n: (out[n]["n_impacts"], out[n]["evidence"])) if has else None
    return out
