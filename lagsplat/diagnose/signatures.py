"""The chart-invariant signatures of a residual (envelope of the decay, frequency against amplitude and time,
spectral peaks, excursion asymmetry) and the residual's principal directions: the evidence the selection of
:mod:`lagsplat.diagnose.select` reads beside its regressions (paper §3.3 diagnosis)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from lagsplat.diagnose.decay_law import decay_law
from lagsplat.diagnose.impacts import impact_signature
from lagsplat.diagnose.residual_data import Residual
from lagsplat.diagnose.spectrum import frequency_allowed, reference_frequencies, residual_peaks

__all__ = ["directions", "signatures", "turning_points", "turning_gap"]


def directions(res: Residual, n_angles: int = 12) -> list[np.ndarray]:
    """Latent directions a candidate is tried along (unit ``[d]`` vectors).

    ``d = 1``: ``[1]``; ``d = 2``: ``n_angles`` angles over a half turn;
    ``d >= 3``: the eigenvectors of ``G_bar`` and of the residual covariance, and the axes.
    """
    d = res.d
    if d == 1:
        return [np.ones(1)]
    if d == 2:
        return [np.array([math.cos(a), math.sin(a)]) for a in np.arange(n_angles) * math.pi / n_angles]
    out = list(np.linalg.eigh(0.5 * (res.G + res.G.T))[1].T) + list(np.linalg.eigh(np.cov(res.r.T))[1].T) + list(np.eye(d))
    return [v / np.linalg.norm(v) for v in out]


# ---------------------------------------------------------------------- evidence
#: smallest amplitude, in chart-noise levels, at which a turning point enters the envelope or a period the timing
MIN_AMPLITUDE_OVER_NOISE = 3.0

#: peak-to-peak range, in chart-noise levels, within which the motion counts as at rest (:func:`_rest`)
REST_BAND_OVER_NOISE = 6.0

def turning_points(p: np.ndarray, t: np.ndarray, min_gap: int, refine: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The turning points (extrema) of an oscillation ``p [n]`` sampled at times ``t [n]`` (s).

    Maxima and minima are each at least ``min_gap`` samples from their own kind (:func:`turning_gap`).
    With ``refine``, each one's time and value are the vertex of the least-squares parabola through the
    five samples around it (three at a segment's edge; the vertex kept within one sample): a half period of
    16 frames is then timed to a small fraction of a frame instead of to the nearest frame.

    Returns:
        ``(idx [k] int, times [k] s, values [k], kind [k])`` in time order; ``values`` in the units of ``p``
        (signed), ``kind`` +1 for a maximum and -1 for a minimum.
    """
    from scipy.signal import find_peaks

    i_max, _ = find_peaks(p, distance=max(1, min_gap))
    i_min, _ = find_peaks(-p, distance=max(1, min_gap))
    idx = np.concatenate([i_max, i_min])
    kind = np.concatenate([np.ones(len(i_max)), -np.ones(len(i_min))])
    order = np.argsort(idx, kind="stable")
    idx, kind = idx[order], kind[order]
    times, values = t[idx].astype(np.float64), p[idx].astype(np.float64)
    if refine:
        for k, i in enumerate(idx):
            h = min(2, i, len(p) - 1 - i)
            if h < 1:
                continue
            x = np.arange(-h, h + 1, dtype=np.float64)
            a, b, c = np.polyfit(x, p[i - h : i + h + 1], 2)
            if a * kind[k] >= 0:  # not curved towards the centre: keep the sample
                continue
            xv = float(np.clip(-b / (2 * a), -1.0, 1.0))
            j = i + (1 if xv > 0 else -1)
            times[k] = t[i] + abs(xv) * (t[j] - t[i])
            values[k] = a * xv * xv + b * xv + c
    return idx, times, values, kind


def _extrema(p: np.ndarray, t: np.ndarray, min_gap: int) -> tuple[np.ndarray, np.ndarray]:
    """Times and absolute values of the alternating extrema (turning points) of a centred oscillation."""
    _, times, values, _ = turning_points(p, t, min_gap)
    return times, np.abs(values)


def turning_gap(f_hz: float, dt: float) -> int:
    """Samples between neighbouring turning points of the same kind: 0.35 periods at ``f_hz`` (Hz), frames ``dt`` (s)
    apart (5 without a frequency)."""
    return int(0.35 / (f_hz * dt)) if math.isfinite(f_hz) and f_hz > 0 else 5


def _turning_gap(res: Residual) -> int:
    """:func:`turning_gap` at the residual's dominant frequency."""
    return turning_gap(res.f_dominant_hz, res.dt)


def _segments(res: Residual, p: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """Per segment of the residual: ``(pk, tk, te, ae)``, the trajectory ``p`` about its median and its times, and
    the times and absolute values of its turning points (:func:`_extrema`, :func:`_turning_gap` apart).
    Read once by both the envelope and the timing."""
    gap = _turning_gap(res)
    out = []
    for idx in res.segment_slices():
        pk, tk = p[idx] - np.median(p[idx]), res.t[idx]
        out.append((pk, tk, *_extrema(pk, tk, gap)))
    return out


def _envelope(res: Residual, segs: list[tuple[np.ndarray, ...]]) -> dict[str, Any]:
    """Fit linear, exponential and hyperbolic envelopes (shared rate, one intercept per segment) to the turning-point
    amplitudes of :func:`_segments`."""
    T, TA, A, S, SG = [], [], [], [], []
    for k, (pk, tq, tk, ak) in enumerate(segs):
        keep = ak > MIN_AMPLITUDE_OVER_NOISE * float(np.max(res.noise_q))
        if keep.sum() >= 3:
            T.append(tk[keep] - tk[keep][0])
            TA.append(tk[keep])
            A.append(ak[keep])
            S.append(np.full(int(keep.sum()), k))
            SG.append(np.sign(np.interp(tk[keep], tq, pk)))  # upper (+1) or lower (-1) turning point
    if not T:
        return {"n_turning_points": 0, "best": None}
    t, a, s = np.concatenate(T), np.concatenate(A), np.concatenate(S)
    # what a rate's precision and the periods a longer recording would add are read from (lagsplat.diagnose.identifiability)
    spread = {"noise": float(np.max(res.noise_q)), "n_segments": len(T), "span_s": float(np.mean([tk[-1] for tk in T])),
              "sxx_s2": float(sum(np.sum((tk - tk.mean()) ** 2) for tk in T)),
              "amplitude_max": float(a.max()), "amplitude_min": float(a.min()), "amplitude_mean": float(a.mean())}  # fmt: skip
    ta = np.concatenate(TA)
    ta = ta - ta.mean()
    segs = np.unique(s)
    D = (s[:, None] == segs[None]).astype(float)

    def lin(y: np.ndarray, wgt: np.ndarray, power: int = 1) -> tuple[np.ndarray, np.ndarray]:
        # a rate that changes in time changes with the recording's clock, not with the time since a segment began:
        # the quadratic term is in the recording's (centred) time, so the takes of one recording share one drift
        X = np.concatenate([D, t[:, None], *(ta[:, None] ** k for k in range(2, power + 1))], 1)
        sw = np.sqrt(wgt)
        c = np.linalg.lstsq(X * sw[:, None], y * sw, rcond=None)[0]
        return c, X @ c

    out: dict[str, Any] = {"n_turning_points": int(len(a)), **spread}
    c, fit = lin(a, np.ones_like(a))
    out["linear"] = {"rate_per_s": float(-c[-1]), "sse": float(np.sum((a - fit) ** 2))}
    c, fit = lin(np.log(a), a**2)
    out["exponential"] = {"rate_per_s": float(-c[-1]), "sse": float(np.sum((a - np.exp(fit)) ** 2))}
    c, fit = lin(1.0 / a, a**4)
    with np.errstate(divide="ignore"):
        out["hyperbolic"] = {"rate_per_unit_s": float(c[-1]), "sse": float(np.sum((a - 1.0 / np.where(fit > 0, fit, np.nan)) ** 2))}
    c, fit = lin(np.log(a), a**2, power=2)  # the decay rate itself changing in time (a drifting damping)
    out["accelerating"] = {"rate_per_s": float(-c[-2]), "rate_change_per_s2": float(-2.0 * c[-1]), "sse": float(np.sum((a - np.exp(fit)) ** 2))}
    forms = {k: out[k]["sse"] for k in ("linear", "exponential", "hyperbolic") if math.isfinite(out[k]["sse"])}
    if forms:
        best = min(forms, key=forms.get)  # type: ignore[arg-type]
        out["best"] = best
        out["sse_ratio_to_best"] = {k: float(v / max(forms[best], 1e-300)) for k, v in forms.items()}
    else:
        out["best"] = None
    out["support"] = _envelope_support(out, len(a), len(segs))
    out["level"] = _decay_level(t, a, np.concatenate(SG), D)
    return out


def _decay_level(t: np.ndarray, a: np.ndarray, side: np.ndarray, D: np.ndarray) -> dict[str, float]:
    """The turning points' exponential decay rate with its standard error, for how well the recording fixes the damping.

    ``log a`` (weights ``a^2``, amplitude errors) on one intercept per segment ``D [n, s]``, the time since the
    segment's first turning point ``t [n]`` and the side ``side [n]`` (+1 upper, -1 lower turning point): a centre
    a little off the segment's median makes the two sides' amplitudes differ by a constant, which a short clip's
    rate would otherwise carry as noise. ``{"rate_per_s", "se", "z", "sse", "dof"}``: ``sse`` in amplitude units
    and ``dof`` its degrees of freedom; ``z`` ``nan`` without one.
    """
    X = np.concatenate([D, side[:, None], t[:, None]], 1)
    if np.linalg.matrix_rank(X) < X.shape[1]:  # one side only: the side is an intercept
        X = np.concatenate([D, t[:, None]], 1)
    dof = len(a) - X.shape[1]
    sw = a
    c = np.linalg.lstsq(X * sw[:, None], np.log(a) * sw, rcond=None)[0]
    fit = X @ c
    out = {"rate_per_s": float(-c[-1]), "sse": float(np.sum((a - np.exp(fit)) ** 2)), "dof": int(dof), "se": math.nan, "z": math.nan}
    if dof >= 1:
        s2 = float(np.sum((sw * (np.log(a) - fit)) ** 2)) / dof
        out["se"] = float(math.sqrt(max(s2 * np.linalg.pinv((X * sw[:, None]).T @ (X * sw[:, None]))[-1, -1], 0.0)))
        out["z"] = out["rate_per_s"] / max(out["se"], 1e-300)
    return out


#: fewest turning points (beyond one intercept per segment) for an envelope to count as evidence
MIN_TURNING_POINTS = 4

#: fewest periods (zero crossing to the second next) the frequency signature needs before it regresses them on amplitude^2 and time
MIN_TIMING_PERIODS = 6

#: fewest such periods from which the timing's evidence for a drift at a given amplitude (``support_time``) is read
MIN_DRIFT_PERIODS = 8


def _envelope_support(env: dict[str, Any], n: int, n_segments: int) -> dict[str, float]:
    """The evidence of the turning points for a linear or a hyperbolic envelope over the exponential (viscous) one,
    and for a decay rate that changes in time (``accelerating``: ``log A`` quadratic in time) over the best of the three.

    The three fits have the same parameters (an intercept per segment, one rate), so the
    difference of their information criteria is ``n log(SSE_exp / SSE_form)`` (Gaussian errors of
    unknown variance): positive favours the form, on the scale of the regressions' ``Delta BIC``
    (10: very strong, Kass & Raftery 1995). The changing rate has one parameter more:
    ``n log(SSE_best / SSE_accelerating) - log n``. Zero with fewer than :data:`MIN_TURNING_POINTS`
    turning points beyond the intercepts.
    """
    out = {"linear": 0.0, "hyperbolic": 0.0, "accelerating": 0.0}
    if n - n_segments < MIN_TURNING_POINTS:
        return out
    exp_sse = env["exponential"]["sse"]
    for form in ("linear", "hyperbolic"):
        sse = env[form]["sse"]
        if math.isfinite(sse) and sse > 0 and math.isfinite(exp_sse) and exp_sse > 0:
            out[form] = float(n * math.log(exp_sse / sse))
    best = min((env[k]["sse"] for k in ("linear", "exponential", "hyperbolic") if math.isfinite(env[k]["sse"])), default=math.nan)
    acc = env["accelerating"]["sse"]
    if math.isfinite(best) and best > 0 and math.isfinite(acc) and acc > 0 and n - n_segments > MIN_TURNING_POINTS:
        out["accelerating"] = float(n * math.log(best / acc) - math.log(n))  # one parameter more than the other forms
    return out


def _rest(res: Residual, p: np.ndarray) -> dict[str, Any]:
    """Where the motion along ``p`` comes to rest, and how far from the centre of its oscillation.

    Per segment, the rest is the last stretch (at least half a dominant period, and the
    segment's end) whose whole range stays within :data:`REST_BAND_OVER_NOISE` (6) chart-noise levels, after an oscillation
    larger than ``10`` noise levels. The centre is the median midpoint of the last four pairs of
    consecutive turning points. A viscous decay comes to rest at its centre; dry friction sticks
    anywhere within ``+- mu / k`` of it (an *off-centre* rest). The evidence is ``z^2 - log N``,
    ``z`` the offset in noise levels (a one-parameter test on the rest position), ``N`` the
    samples at rest; ``0`` when nothing rests.
    """
    f = res.f_dominant_hz
    period = int(round(1.0 / (f * res.dt))) if math.isfinite(f) and f > 0 else 30
    gap = max(1, int(0.35 * period))
    noise = float(np.max(res.noise_q))
    best: dict[str, Any] = {"at_rest": False, "support": 0.0}
    for idx in res.segment_slices():
        pk, tk = p[idx], res.t[idx]
        if len(pk) < 2 * period or np.ptp(pk) < 10 * noise:
            continue
        # the earliest start from which the rest of the segment stays within the band
        hi, lo = np.maximum.accumulate(pk[::-1])[::-1], np.minimum.accumulate(pk[::-1])[::-1]
        still = np.flatnonzero(hi - lo <= REST_BAND_OVER_NOISE * noise)
        if not len(still) or len(pk) - still[0] < max(period // 2, 3):
            continue
        i0 = int(still[0])
        from scipy.signal import find_peaks

        ext = np.sort(np.concatenate([find_peaks(pk[:i0], distance=gap)[0], find_peaks(-pk[:i0], distance=gap)[0]]))
        if len(ext) < 2:
            continue
        mids = 0.5 * (pk[ext[1:]] + pk[ext[:-1]])[-4:]
        centre, rest = float(np.median(mids)), float(np.mean(pk[i0:]))
        z = (rest - centre) / max(noise, 1e-300)
        n_rest = len(pk) - i0
        support = max(0.0, z * z - math.log(n_rest))
        if support >= best["support"]:
            best = {
                "at_rest": True, "rest_time_s": float(tk[i0]), "rest_position": rest, "centre": centre, "offset": rest - centre,
                "offset_over_noise": float(z), "last_amplitude": float(np.max(np.abs(pk[ext] - centre))), "support": float(support),
            }  # fmt: skip
    return best


def _frequency(res: Residual, segs: list[tuple[np.ndarray, ...]]) -> dict[str, Any]:
    """Period-by-period frequency regressed on amplitude^2 and time (Duffing shift vs drift), per segment of :func:`_segments`.

    ``corr_amp2_time`` is the correlation of the periods' squared amplitudes with their mid-times: near -1
    on one freely decaying take, where a frequency that depends on the amplitude and one that drifts in
    time change the periods alike.

    Each period runs between two zero crossings in the same direction (an offset of the centre shifts
    alternate half periods in opposite directions and cancels there). Its amplitude is the envelope of
    the turning points at the period's mid-time (linear interpolation), not the largest excursion inside
    it: two consecutive periods share that excursion, so it steps in pairs while the mid-time rises, and
    a time trend then explains what is only the difference of the periods that start on a rising and on
    a falling crossing. That difference (the crossings move with a decaying amplitude when the crossing
    level is not the exact centre of the swing) gets its own column, +-1 by the crossing's direction.
    """
    F, A2, TT, UP = [], [], [], []
    for pk, tk, te, ae in segs:
        sgn = np.signbit(pk)
        cross = np.flatnonzero(sgn[1:] != sgn[:-1])
        if len(cross) < 3 or len(te) < 2:
            continue
        tc = tk[cross] - pk[cross] * (tk[cross + 1] - tk[cross]) / (pk[cross + 1] - pk[cross])
        for a, b, i0 in zip(tc[:-2], tc[2:], cross[:-2]):
            amp = float(np.interp(0.5 * (a + b), te, ae))
            if amp <= MIN_AMPLITUDE_OVER_NOISE * float(np.max(res.noise_q)) or b <= a:
                continue
            F.append(1.0 / (b - a))
            A2.append(amp * amp)
            TT.append(0.5 * (a + b))
            UP.append(1.0 if pk[i0] < 0 else -1.0)
    if len(F) < MIN_TIMING_PERIODS:  # too few to regress, enough for the frequency itself
        return {"n_periods": len(F), **({"f_mean_hz": float(np.mean(F))} if F else {})}
    F, A2, TT, UP = map(np.asarray, (F, A2, TT, UP))
    alt = UP - UP.mean()
    X = np.stack([np.ones_like(F), A2 - A2.mean(), TT - TT.mean(), alt], 1)
    c, *_ = np.linalg.lstsq(X, F, rcond=None)
    r = F - X @ c
    s2 = float(r @ r) / max(len(F) - X.shape[1], 1)
    se = np.sqrt(2.0 * np.maximum(np.diag(s2 * np.linalg.pinv(X.T @ X)), 0.0))  # x sqrt(2): consecutive periods overlap by half
    # along one direction of a chart with several degrees of freedom the modes beat, and the crossings' timing
    # changes with their phase, not with a drifting stiffness: no evidence for a drift there
    return {**(_time_support(F, A2, TT, alt) if res.d == 1 else {"support_time": 0.0}),
        "n_periods": int(len(F)), "f_mean_hz": float(c[0]),
        "slope_amp2": float(c[1]), "slope_amp2_se": float(se[1]), "z_amp2": float(c[1] / max(se[1], 1e-300)),
        "relative_shift_at_max_amplitude": float(c[1] * A2.max() / c[0]),
        "slope_time": float(c[2]), "slope_time_se": float(se[2]), "z_time": float(c[2] / max(se[2], 1e-300)),
        "relative_change_over_span": float(c[2] * np.ptp(TT) / c[0]),
        "corr_amp2_time": float(np.corrcoef(A2, TT)[0, 1]) if A2.std() > 0 and TT.std() > 0 else 0.0,
    }  # fmt: skip


def _time_support(F: np.ndarray, A2: np.ndarray, TT: np.ndarray, alt: np.ndarray) -> dict[str, float]:
    """Evidence that the frequency changes with time at a given amplitude (a drift), on the ``Delta BIC`` scale.

    The period-by-period frequencies ``F [n]`` (Hz) are fitted by any quadratic function of the squared
    amplitude ``A2 [n]`` (a Duffing spring, a pendulum, an end stop that is hit harder at larger
    amplitude) and the crossing-direction column ``alt [n]`` (:func:`_frequency`), then by the same plus a
    linear trend in the periods' mid-times ``TT [n]`` (s); the support is the information criterion of the
    second over the first, ``n_eff log(SSR_amplitude / SSR_amplitude+time) - log n_eff`` with
    ``n_eff = n / 2`` (consecutive periods share half their samples). Where the amplitude itself falls
    steadily with time the two cannot be told apart and the support stays near zero: a drift is claimed
    only where the timing changes in a way no dependence on the amplitude explains. ``support_time`` 0
    with fewer than :data:`MIN_DRIFT_PERIODS` periods.
    """
    n = len(F)
    if n < MIN_DRIFT_PERIODS:
        return {"support_time": 0.0}
    a = (A2 - A2.mean()) / max(float(A2.std()), 1e-300)
    X0 = np.stack([np.ones(n), a, a * a, alt], 1)
    X1 = np.column_stack([X0, TT - TT.mean()])
    ssr = [float(np.sum((F - X @ np.linalg.lstsq(X, F, rcond=None)[0]) ** 2)) for X in (X0, X1)]
    n_eff = n / 2.0
    sup = n_eff * math.log(max(ssr[0], 1e-300) / max(ssr[1], 1e-300)) - math.log(n_eff)
    return {"support_time": float(sup)}


def _turning(res: Residual, e: np.ndarray) -> dict[str, Any]:
    """How sharply the motion turns around on either side, on the chart's own (unsmoothed) positions along ``e``.

    At each turning point (an extremum at least 0.35 dominant periods from its neighbours) a parabola through
    the five samples around it gives the curvature towards the centre; the log-curvatures of the upper and of
    the lower turning points are compared. A cubic stiffness, like any odd restoring force, turns the motion
    around alike on both sides; a stop far stiffer than the spring reverses it within a few frames on its
    side. ``support``: the information criterion of two mean log-curvatures over one (``Delta BIC`` scale);
    ``ratio``: the sharper side's median curvature over the other's (>= 1). Empty on a chart with ``d > 1``
    (the modes beat along any one direction) or with fewer than two turning points on a side.
    """
    if res.d != 1:
        return {}
    gap = _turning_gap(res)
    from scipy.signal import find_peaks

    curv: dict[str, list[float]] = {"upper": [], "lower": []}
    x = res.q_raw @ np.asarray(e, np.float64)
    tt = np.arange(-2.0, 3.0)
    for idx in res.segment_slices():
        p = x[idx]
        for side, sgn in (("upper", 1.0), ("lower", -1.0)):
            for i in find_peaks(sgn * p, distance=max(1, gap))[0]:
                if 2 <= i < len(p) - 2:
                    c = -sgn * 2.0 * np.polyfit(tt, p[i - 2 : i + 3], 2)[0]
                    if c > 0:
                        curv[side].append(float(c))
    if min(len(curv["upper"]), len(curv["lower"])) < 2:
        return {}
    lu, ll = np.log(curv["upper"]), np.log(curv["lower"])
    y = np.concatenate([lu, ll])
    n = len(y)
    ssr0 = float(np.sum((y - y.mean()) ** 2))
    ssr1 = float(np.sum((lu - lu.mean()) ** 2) + np.sum((ll - ll.mean()) ** 2))
    support = n * math.log(max(ssr0, 1e-300) / max(ssr1, 1e-300)) - math.log(n)
    up, lo = float(np.median(curv["upper"])), float(np.median(curv["lower"]))
    return {"upper": up, "lower": lo, "n_upper": len(lu), "n_lower": len(ll), "ratio": max(up, lo) / min(up, lo),
            "sharper_side": "upper" if up > lo else "lower", "support": float(support), "direction": [float(v) for v in e]}  # fmt: skip


def turns_one_sided(turning: dict[str, Any], thresholds: dict[str, float]) -> bool:
    """Whether one side turns the motion around at least ``min_one_sided_turning`` (2) times as sharply as the other,
    with very strong evidence (``support >= min_delta_bic``, 10): the :func:`_turning` signature's reading, shared by
    the cubic stiffness it sets aside and the end stop it supports."""
    return (turning.get("ratio", 1.0) >= thresholds.get("min_one_sided_turning", 2.0)
            and turning.get("support", 0.0) >= thresholds.get("min_delta_bic", 10.0))  # fmt: skip


def timing_drifts(frequency: dict[str, Any], thresholds: dict[str, float]) -> bool:
    """Whether the recorded periods drift in time, at a given amplitude, with very strong evidence and by a physical
    amount: the frequency signature's ``support_time`` at least ``min_delta_bic`` (10) and its change over the
    recording at least half ``min_cubic_shift`` (the size a cubic stiffness's own timing must show). A long clean
    recording makes a change of a few tenths of a percent significant; it then does not outweigh a stiffness that
    moves the frequency with the amplitude by several percent."""
    sup = float(frequency.get("support_time", 0.0))
    change = abs(float(frequency.get("relative_change_over_span", 0.0)))
    return sup >= thresholds.get("min_delta_bic", 10.0) and change >= 0.5 * thresholds.get("min_cubic_shift", 0.03)


def signatures(res: Residual, model_freqs_hz: Sequence[float] | None = None, direction: np.ndarray | None = None) -> dict[str, Any]:
    """The physical signatures of an unmodelled effect, read off the trajectory and residual.

    Along ``direction`` (default the most visible one, top eigenvector of ``G``):

    * ``envelope``: turning-point amplitudes fitted with a linear (dry
      friction), exponential (viscous) and hyperbolic (quadratic drag) decay,
      one rate shared by all segments; ``best`` and the SSE ratios; the chart noise
      (``noise``), the takes read (``n_segments``), their mean span and the turning points'
      sum of squared time deviations from each take's mean (``span_s``, ``sxx_s2``) and their
      largest, smallest and mean amplitude, and the exponential rate with its standard error
      (``level``, :func:`_decay_level`): what the damping's precision is read from.
    * ``frequency``: frequency of each period (between zero crossings in the same
      direction, so an offset cancels) regressed on ``amplitude^2``
      (Duffing shift: > 0 hardening, < 0 softening or a pendulum) and on time
      (drift), slopes with standard errors and z-scores; the time's evidence
      (``support_time``) is 0 on a chart with ``d > 1``, whose modes beat along
      any one direction.
    * ``spectrum``: strongest peaks of the residual's power spectrum, and those
      where a periodic force or hidden mode would be sought
      (:func:`~lagsplat.diagnose.spectrum.frequency_allowed`: away from the model's
      modes, the motion's own frequency, their harmonics and combination tones
      and the logged inputs' frequencies; a force or a mode the model lacks).
      A nonlinear model's modes at rest can sit well off the frequency it moves
      at on the clip (as a learned potential on a realistic spring cart did;
      ``docs/experiments/code_comment_history.md``): a residual at the motion's own
      frequency is a stiffness or damping misfit, not a force the model lacks.
    * ``asymmetry``: ratio of the largest excursions on either side of the
      median (a one-sided stop clips one side).
    * ``rest``: where the motion comes to rest and its offset from the centre of the
      oscillation (dry friction sticks off-centre).
    * ``turning``: how sharply the motion turns around on either side (:func:`_turning`;
      a stop reverses it within a few frames on its side, an odd force alike on both).
    * ``impacts``: the turning points where the motion arrives at speed and reverses at a fixed
      position, their side and the restitution (:func:`~lagsplat.diagnose.impacts.impact_signature`).
    * ``decay_law``: the whole training trajectory's evidence for a dry-friction or a quadratic-drag
      decay over a viscous one (:func:`~lagsplat.diagnose.decay_law.decay_law`; unactuated ``d = 1``
      charts with a segment of at least two periods, else empty).

    The envelope's ``support``, the decay law's and the rest's ``support`` are evidence on the ``Delta BIC``
    scale that the candidates read (:meth:`~lagsplat.diagnose.effect_base.Effect.signature_support`).

    Args:
        res: the residual.
        model_freqs_hz: the model's modal frequencies, Hz (default ``res.meta["model_freqs_hz"]``, or none;
            the trajectory's dominant frequency counts besides them).
        direction: ``[d]`` unit direction.

    Returns:
        A JSON-serialisable dict.
    """
    e = np.asarray(direction, np.float64) if direction is not None else None
    p = res.project(e)
    from lagsplat import metrics

    e_top = metrics.top_direction(res.G) if e is None else e
    segs = _segments(res, p)
    out: dict[str, Any] = {"envelope": _envelope(res, segs), "frequency": _frequency(res, segs)}
    peaks = residual_peaks(res.r @ e_top, res.segment, res.dt, 4)
    unexplained = [f for f in peaks if frequency_allowed(res, f, model_freqs_hz)]
    out["spectrum"] = {"residual_peaks_hz": peaks, "model_freqs_hz": reference_frequencies(res, model_freqs_hz), "unexplained_peaks_hz": unexplained}
    pc = p - np.median(p)
    hi, lo = float(np.quantile(pc, 0.995)), float(-np.quantile(pc, 0.005))
    out["asymmetry"] = {"upper": hi, "lower": lo, "ratio": float(max(hi, lo) / max(min(hi, lo), 1e-300))}
    out["rest"] = _rest(res, p)
    out["turning"] = _turning(res, e_top)
    out["impacts"] = _impacts(res, e_top)
    out["decay_law"] = decay_law(res, e_top)
    return out


def _impacts(res: Residual, e: np.ndarray) -> dict[str, Any]:
    """:func:`~lagsplat.diagnose.impacts.impact_signature` on the chart's own positions along ``e`` (``d = 1`` charts:
    on a larger chart the modes beat along any one direction), with the direction; empty otherwise. It reads every
    frame of each segment (:attr:`~lagsplat.diagnose.residual_data.SegmentState.whole`), the edges the residual trims
    included: the first swings strike hardest, and a low restitution leaves only a few impacts to read."""
    if res.d != 1:
        return {}
    whole = [st.q_raw[st.whole] for st in res.states]
    ends = np.cumsum([0] + [len(w) for w in whole])
    segments = [np.arange(a, b) for a, b in zip(ends[:-1], ends[1:])]
    sig = impact_signature(np.concatenate(whole, 0) @ np.asarray(e, np.float64), segments, res.dt, res.f_dominant_hz)
    return {**sig, "direction": [float(v) for v in e]}
