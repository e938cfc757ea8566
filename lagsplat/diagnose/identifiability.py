"""What one recording can and cannot tell: the identifiability section of the diagnosis report.

The diagnosis (paper §3.3: the model class, and the effects it leaves out, paper §5) reads chart-invariant
signatures off the training frames (:func:`~lagsplat.diagnose.signatures.signatures`). Some quantities a
recording fixes whatever its length: the frequency as soon as a period is timed. Others it cannot fix,
however good the chart: on one take released once, the amplitude falls steadily with time, so a frequency
that depends on the amplitude (a hardening spring) and a stiffness that drifts over the recording change the
periods alike; over three periods a linear (dry friction) and an exponential (viscous) envelope are within
the noise. :func:`identifiability` turns the report's records into one entry per quantity: determined or
not, why (with the numbers), and what recording would settle it.

Thresholds are those of the report's reading (:mod:`lagsplat.diagnose.reading`: ``STRONG_Z``, ``WEAK_Z``,
``CONFOUNDED``, ``INDISTINGUISHABLE``) and of the selection (``min_delta_bic`` of the record's settings).
The "N more periods" estimates extrapolate the evidence the recording holds at its own noise, each by the
rule its docstring states; they are estimates, not guarantees.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from lagsplat.diagnose.decay_law import LAW_NAMES, LAWS, law_evidence
from lagsplat.diagnose.reading import CONFOUNDED, INDISTINGUISHABLE, STRONG_Z, WEAK_Z, indistinguishable
from lagsplat.diagnose.signatures import MIN_AMPLITUDE_OVER_NOISE, MIN_DRIFT_PERIODS, MIN_TURNING_POINTS, REST_BAND_OVER_NOISE

__all__ = ["identifiability"]

#: What a second take should be released at, the report's words: any release amplitude other than this take's puts
#: the same amplitude at another time of the recording, which is all that separates a law of the amplitude from a drift.
OTHER_AMPLITUDE = "a second take released at about half (or twice) this amplitude"

_FORM_OF_LAW = {"dry": "linear", "drag": "hyperbolic"}  # the envelope form that reads each decay law


def _num(x: Any) -> float:
    return float(x) if isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) else float("nan")


def _record(quantity: str, determined: bool, why: str, settle_by: str | None = None) -> dict[str, Any]:
    return {"quantity": quantity, "determined": bool(determined), "why": why, "settle_by": None if determined else settle_by}


def _periods(n_timed: int) -> float:
    """Whole periods behind ``n_timed`` timed periods (zero crossing to the second next: two per period, overlapping by half)."""
    return 0.5 * (n_timed + 1)


def _ev_text(v: float) -> str:
    """An evidence in the report's words: ``-inf`` is a law whose coefficient took the other law's sign."""
    return f"{v:.1f}" if math.isfinite(v) else "none (its coefficient takes the wrong sign)"


def _more(x: float) -> str:
    """``"about N more periods"``, ``N`` the estimate ``x`` rounded up, at least one."""
    n = max(1, math.ceil(x))
    return f"about {n} more period{'s' if n > 1 else ''}"


def _frequency_hz(fr: Mapping[str, Any], gap: Mapping[str, Any]) -> float:
    """The motion's frequency: the timed periods' mean, else the encoded held-out frames' (``nan`` if neither)."""
    f = _num(fr.get("f_mean_hz"))
    return f if f > 0 else _num(((gap or {}).get("before") or {}).get("f_enc_hz"))


def _natural_frequency(fr: Mapping[str, Any], gap: Mapping[str, Any], f: float) -> dict[str, Any]:
    """Determined once one period is timed above the chart noise (a frequency needs no more); the held-out frames' reading beside it."""
    n = int(fr.get("n_periods") or 0)
    if n < 1 or not f > 0:  # f: the timed periods' mean, whatever their number
        return _record("natural frequency", False, "no whole period above the chart noise is timed on the training frames",
                       "a recording that holds a few whole periods of the motion above the chart noise")  # fmt: skip
    why = f"about {_periods(n):g} periods timed on the training frames, {f:.3g} Hz"
    before = (gap or {}).get("before") or {}
    if _num(before.get("f_enc_hz")) > 0 and _num(before.get("f_sim_hz")) > 0:
        why += (f"; the held-out frames read {before['f_enc_hz']:.3g} Hz and the identified model {before['f_sim_hz']:.3g} Hz "
                f"(error {100 * _num(before.get('eps_freq')):.2g} %)")  # fmt: skip
    if abs(_num(fr.get("z_amp2"))) >= STRONG_Z:
        why += "; it moves with the amplitude, so this is the frequency at the recorded amplitudes, the small-swing one an extrapolation"
    return _record("natural frequency", True, why)


def _damping_level(env: Mapping[str, Any], f: float, takes: int) -> dict[str, Any]:
    """Determined when the turning points fall with ``z >= STRONG_Z``: the envelope's side-corrected exponential rate
    over its standard error (``level``, :func:`~lagsplat.diagnose.signatures._decay_level`).

    "About N more periods": at a steady decay and a constant noise ``Sxx`` grows as the cube of the number of
    turning points ``m``, so ``z`` grows as ``m^(3/2)``: ``m_needed = m (STRONG_Z / z)^(2/3)``, two turning points a period.
    """
    n = int(env.get("n_turning_points") or 0)
    need = takes + 2  # an intercept per take, the rate, and one degree of freedom for the noise
    if not env.get("best") or n < need:
        return _record("damping level", False, f"{n} turning points above {MIN_AMPLITUDE_OVER_NOISE:g} chart-noise levels: too few to read a decay rate",
                       f"{_more((need - n) / 2)} of the free decay")  # fmt: skip
    level = env.get("level") or {}
    z, r = _num(level.get("z")), _num(level.get("rate_per_s"))
    zeta = f" (damping ratio about {100 * r / (2 * math.pi * f):.2g} %)" if f > 0 and r > 0 else ""
    if z >= STRONG_Z:
        return _record("damping level", True, f"the turning points' amplitude falls at {r:.3g} /s{zeta}, z = {z:.1f} over {n} turning points")
    if not math.isfinite(z):
        return _record("damping level", False, "the record carries no standard error for the turning points' rate", "a recording diagnosed anew")
    if z <= -STRONG_Z:
        return _record("damping level", False, f"the turning points' amplitude grows (z = {z:.1f}): the motion is driven, not a free decay",
                       "a recording of the free decay, released and left alone")  # fmt: skip
    why = f"the turning points' fall over {n} turning points is within the noise (z = {z:.1f})"
    if not z > 0:
        return _record("damping level", False, why, "a longer recording in which the amplitude visibly falls (none is seen here)")
    more = _more((n * (STRONG_Z / z) ** (2 / 3) - n) / 2 / takes)
    return _record("damping level", False, why, f"{more}{' per take' if takes > 1 else ''} (estimate: at a steady decay z "
                   "grows as the number of turning points to the power 3/2)")  # fmt: skip


def _form_evidence(ev: Mapping[str, Any]) -> dict[str, tuple[float, str]]:
    """Per decay law, its strongest evidence over viscous damping and where it was read (the whole trajectory's fit, the turning points)."""
    law, sup = ev.get("decay_law") or {}, (ev.get("envelope") or {}).get("support") or {}
    out = {}
    for k in LAWS:
        cands = [(law_evidence(law, k), "whole-trajectory fit"), (_num(sup.get(_FORM_OF_LAW[k])), "turning points")]
        out[k] = max(((v, w) for v, w in cands if math.isfinite(v)), default=(float("nan"), ""))
    return out


def _form_settle(env: Mapping[str, Any], f: float, min_ev: float, has_law: bool) -> str:
    """The recording a decay-form decision needs, by the envelope's curvature (``r`` the ``level`` rate, ``sigma^2`` the
    exponential fit's SSE per degree of freedom: the noise the forms' comparison itself reads against).

    Over a take of span ``T`` the exponential envelope ``a exp(-r t)`` and a linear or hyperbolic one of the same initial
    slope differ by ``a r^2 t^2 / 2``; its part no straight line absorbs has rms ``a r^2 T^2 / (2 sqrt(180))``, so ``m``
    turning points at noise ``sigma`` give an expected evidence ``E = m (a r^2 T^2 / 2)^2 / (180 sigma^2)``. With turning
    points at a fixed rate ``E`` grows as ``T^5``: ``T_needed = T (min_delta_bic / E)^(1/5)``. A decay that falls to
    :data:`~lagsplat.diagnose.signatures.MIN_AMPLITUDE_OVER_NOISE` chart-noise levels first needs a larger release instead.
    """
    n, takes = int(env.get("n_turning_points") or 0), int(env.get("n_segments") or 1)
    r, sse = _num((env.get("level") or {}).get("rate_per_s")), _num((env.get("exponential") or {}).get("sse"))
    a, T, noise = _num(env.get("amplitude_mean")), _num(env.get("span_s")), _num(env.get("noise"))
    if not T > 0 and f > 0:
        T = (n / takes - 1) / (2 * f)
    dof = n - takes - 1
    if not (r > 0 and a > 0 and T > 0 and f > 0 and dof >= 1 and sse > 0):
        return "a longer recording in which the amplitude visibly falls"
    E = n * (a * r * r * T * T / 2) ** 2 / 180.0 / (sse / dof)
    if E >= min_ev:  # the curvature is there to read, yet no form wins: a mix of laws, which their amplitude dependence separates
        return f"{OTHER_AMPLITUDE} (the decay lies between the forms; each law takes the amplitude its own way)"
    T_need = T * (min_ev / E) ** 0.2
    more = _more((T_need - T) * f)
    a_end = _num(env.get("amplitude_min")) * math.exp(-r * (T_need - T))
    if noise > 0 and a_end < MIN_AMPLITUDE_OVER_NOISE * noise:
        return (f"a take released at about {MIN_AMPLITUDE_OVER_NOISE * noise / a_end:.1f}x this amplitude and recorded for {more} "
                "(at this one the swing reaches the chart noise before the forms separate)")  # fmt: skip
    sharper = "; the whole-trajectory fit, which reads every sample, may need fewer" if has_law else ""
    return (f"{more}{' per take' if takes > 1 else ''} (estimate: the curvature that separates the forms grows as the "
            f"span squared, their evidence as its fifth power, expected {E:.1f} now){sharper}")  # fmt: skip


def _damping_form(ev: Mapping[str, Any], f: float, min_ev: float, takes: int) -> list[dict[str, Any]]:
    """Determined: a law reaches ``min_delta_bic`` over viscous damping (:func:`_form_evidence`), or the turning points
    put viscous damping ``min_delta_bic`` ahead of both other forms; else :func:`_form_settle`. On one take a law found
    gets a second record: a damping that drifts over the recording quickens or slows the decay alike."""
    env = ev.get("envelope") or {}
    sup, n = env.get("support") or {}, int(env.get("n_turning_points") or 0)
    forms = _form_evidence(ev)
    best = max(forms, key=lambda k: forms[k][0] if math.isfinite(forms[k][0]) else -math.inf)
    v, where = forms[best]
    if v >= min_ev:
        out = [_record("damping form", True, f"{LAW_NAMES[best]}: evidence {v:.1f} over viscous damping ({where})")]
        acc, q = _num(sup.get("accelerating")), f"damping form: {LAW_NAMES[best]} vs a damping drifting in time"
        if takes == 1:
            trend = "rises" if best == "dry" else "falls"
            out.append(_record(q, False, f"on one take the amplitude falls with time, so a viscous damping that {trend} over the recording would "
                               f"change the decay alike (the envelope's evidence for a rate changing in time: {acc:.1f})",
                               f"{OTHER_AMPLITUDE}: {LAW_NAMES[best]} acts by the amplitude, a drift by the recording's clock"))  # fmt: skip
        elif acc >= min_ev:  # the takes tell them apart, and the rate changes with the recording's clock
            out.append(_record(q, True, f"the {takes} takes put like amplitudes at different times, and the turning points' rate changes with "
                               f"the recording's clock (evidence {acc:.1f}): a damping that drifts, which a law of the amplitude alone does not follow"))  # fmt: skip
        return out
    lin, hyp = _num(sup.get("linear")), _num(sup.get("hyperbolic"))
    if lin <= -min_ev and hyp <= -min_ev:
        return [_record("damping form", True, f"viscous: over {n} turning points the exponential envelope beats a linear (dry friction) "
                        f"one by {-lin:.1f} and a hyperbolic (drag) one by {-hyp:.1f}")]  # fmt: skip
    law = ev.get("decay_law") or {}
    whole = "" if not law else f"; whole-trajectory fit: dry friction {_ev_text(law_evidence(law, 'dry', False))}, drag {_ev_text(law_evidence(law, 'drag', False))}"
    if not env.get("best") or n - takes < MIN_TURNING_POINTS:
        need = MIN_TURNING_POINTS + takes
        return [_record("damping form", False, f"{n} turning points above {MIN_AMPLITUDE_OVER_NOISE:g} chart-noise levels are too few to compare "
                        f"decay forms (the envelope needs {need}{whole})", f"{_more((need - n) / 2)} to read the envelope at all, "
                        "and more to tell the forms apart")]  # fmt: skip
    why = f"{n} turning points leave the three decay forms within {min_ev:g} of each other (turning points: linear {lin:.1f}, hyperbolic {hyp:.1f} over exponential{whole})"
    return [_record("damping form", False, why, _form_settle(env, f, min_ev, bool(law)))]


def _force_shape(ranking: list[Mapping[str, Any]], min_ev: float) -> str:
    """Where the residual's own fit ranks a stiffness law of the state (one with a physical sign that its own check keeps)
    and a drift ``min_delta_bic`` apart, that clause: the force's shape within each period (a cubic's or a stop's
    harmonics) is evidence the periods' timing does not carry."""
    ev = {r.get("effect"): _num(r.get("evidence", r.get("delta_bic"))) for r in ranking}
    kept = {r.get("effect") for r in ranking if r.get("physical", True) and r.get("practical", True)}
    laws = [(v, k) for k, v in ev.items() if k in ("cubic_stiffness", "end_stop") and k in kept and math.isfinite(v)]
    drift = ev.get("drift", float("nan"))
    if not laws or not math.isfinite(drift):
        return ""
    v, k = max(laws)
    if abs(v - drift) < min_ev:
        return ""
    ahead, behind = (k, "a drift") if v > drift else ("drift", k)
    return f"; the residual's force, which also sees the swing's shape within each period, puts {ahead} {abs(v - drift):.1f} ahead of {behind}"


def _amplitude_vs_time(fr: Mapping[str, Any], min_ev: float, takes: int, ranking: list[Mapping[str, Any]] = ()) -> dict[str, Any]:
    """Whether the periods tell a frequency that depends on the amplitude from one that drifts in time.

    Not determined where the periods' squared amplitudes and times are one variable (``|corr| >= CONFOUNDED``: one
    steady decay) and the timing's evidence for a change at a given amplitude (``support_time``) stays below
    ``min_delta_bic``; there the slopes' own ``z`` are no guide either, their standard errors grow as
    ``1 / sqrt(1 - corr^2)``. Elsewhere, not determined while a slope is in the inconclusive band
    ``WEAK_Z <= |z| < STRONG_Z``: a trend's ``z`` grows as the number of periods to the power 3/2.
    """
    q = "frequency: amplitude vs time"
    n = int(fr.get("n_periods") or 0)
    if "z_amp2" not in fr:
        more = _more((MIN_DRIFT_PERIODS - n) / 2)
        return _record(q, False, f"about {_periods(n):g} periods are too few to regress the frequency on amplitude and time",
                       f"{more}" + (f", and {OTHER_AMPLITUDE} to tell the two apart" if takes == 1 else ""))  # fmt: skip
    za, zt, corr, sup = (_num(fr.get(k)) for k in ("z_amp2", "z_time", "corr_amp2_time", "support_time"))
    shift = 100 * _num(fr.get("relative_shift_at_max_amplitude"))
    spring = "hardening" if za > 0 else "softening"
    if abs(corr) >= CONFOUNDED:
        if sup >= min_ev:
            return _record(q, True, f"the amplitude falls steadily (corr(A^2, t) = {corr:.2f}), yet the periods change at a given amplitude "
                           f"(evidence {sup:.1f}): the timing separates a drift from the amplitude's effect")  # fmt: skip
        if abs(za) >= STRONG_Z and abs(za) >= abs(zt):
            seen = (f"the periods {'shorten' if za > 0 else 'lengthen'} with the amplitude ({shift:+.1f} % at the largest, z = {za:.1f}: a {spring} "
                    "spring), but a stiffness drifting in time would read the same")  # fmt: skip
        elif abs(zt) >= STRONG_Z:
            seen = f"the periods drift over the recording (z = {zt:.1f}), but a frequency that depends on the amplitude would read the same"
        else:
            seen = (f"neither slope is resolved (z = {za:.1f} against amplitude, {zt:.1f} against time), and a stiffness that depends on the "
                    "amplitude and one that drifts would read alike")  # fmt: skip
        why = f"{seen}: on this steady decay amplitude and time are one variable (corr(A^2, t) = {corr:.2f}; timing evidence for a drift {sup:.1f}, below {min_ev:g})"
        why += _force_shape(ranking, min_ev)
        settle = f"{OTHER_AMPLITUDE}: a law of the amplitude changes the periods with the swing, a drift with the recording's clock"
        if n < MIN_DRIFT_PERIODS:
            settle += f" (this take also needs {_more((MIN_DRIFT_PERIODS - n) / 2)} for the timing to be read)"
        return _record(q, False, why, settle)
    weak = [(z, w) for z, w in ((za, "amplitude"), (zt, "time")) if WEAK_Z <= abs(z) < STRONG_Z]
    apart = f"amplitude and time vary apart here (corr(A^2, t) = {corr:.2f}, {takes} take{'s' if takes > 1 else ''})"
    if weak:
        z, w = max(weak, key=lambda x: abs(x[0]))
        more = _more((n * (STRONG_Z / abs(z)) ** (2 / 3) - n) / 2)
        return _record(q, False, f"{apart}, but the slope against {w} is not conclusive (z = {z:.1f})",
                       f"{more} (estimate: a trend's z grows as the number of periods to the power 3/2)")  # fmt: skip
    return _record(q, True, f"{apart}: the frequency against amplitude z = {za:.1f}, against time z = {zt:.1f}")


def _rest(rest: Mapping[str, Any], env: Mapping[str, Any], f: float, min_ev: float) -> dict[str, Any] | None:
    """Determined where the motion rests and its offset from the oscillation's centre is either conclusive (``support >=
    min_delta_bic``) or nil (``support`` 0). Not at rest: the periods until the swing falls to half the rest band, at the
    envelope's best-fitting form (linear: a constant fall per second; else the exponential ``level`` rate)."""
    if not rest:
        return None
    q = "where the motion rests"
    if rest.get("at_rest"):
        sup, z = _num(rest.get("support")), abs(_num(rest.get("offset_over_noise")))
        where = f"the motion stops at t = {_num(rest.get('rest_time_s')):.2f} s, {z:.1f} chart-noise levels from the centre of its oscillation"
        if sup >= min_ev:
            return _record(q, True, f"{where}: off-centre, as dry friction sticks (evidence {sup:.1f})")
        if not sup > 0:
            return _record(q, True, f"{where}: at the centre, as a viscous decay rests")
        return _record(q, False, f"{where}: an offset that is not conclusive (evidence {sup:.1f}, below {min_ev:g})",
                       "a second take that comes to rest: dry friction sticks at a different place within its band each time, a viscous decay at the centre")  # fmt: skip
    settle = "a recording that lets the motion come to rest"
    a, noise = _num(env.get("amplitude_min")), _num(env.get("noise"))
    stop = 0.5 * REST_BAND_OVER_NOISE * noise
    b, r = _num((env.get("linear") or {}).get("rate_per_s")), _num((env.get("level") or {}).get("rate_per_s"))
    t_more = (a - stop) / b if env.get("best") == "linear" and b > 0 else (math.log(a / stop) / r if r > 0 and a > stop > 0 else float("nan"))
    if t_more > 0 and f > 0:
        settle += f" ({_more(t_more * f)} at the measured decay, until the swing falls to {0.5 * REST_BAND_OVER_NOISE:g} chart-noise levels)"
    last = f" (the smallest turning point is {a / noise:.0f} chart-noise levels)" if a > 0 and noise > 0 else ""
    return _record(q, False, f"the motion does not come to rest in these frames{last}", settle)


_STATE_LAWS = {"coulomb", "quadratic_drag", "end_stop", "cubic_stiffness"}


def _pair_settle(a: str, b: str) -> str:
    """The recording that separates two candidates the residual ranks alike, by how each scales with the swing or with time."""
    pair = {a, b}
    if "drift" in pair and pair & _STATE_LAWS:
        law = next(iter(pair - {"drift"}))
        return f"{OTHER_AMPLITUDE}: {law} acts by the state, a drift by the recording's clock"
    if pair == {"coulomb", "quadratic_drag"}:
        return "a take released at about twice this amplitude: drag takes a larger share of a larger swing per period, dry friction a smaller one"
    if pair == {"end_stop", "cubic_stiffness"}:
        return "a take released at about half this amplitude, short of the stop: a stop then leaves the periods alone, a cubic spring still shifts them"
    if pair == {"periodic_force", "missing_dof"}:
        return "a longer recording: a hidden mode's oscillation decays with the motion, an unlogged periodic force keeps driving it"
    return f"{OTHER_AMPLITUDE}: each candidate's force changes with the swing in its own way"


def _pairs(ranking: list[Mapping[str, Any]], min_ev: float) -> list[dict[str, Any]]:
    """One record per candidate within :data:`~lagsplat.diagnose.reading.INDISTINGUISHABLE` of the best physical one
    (:func:`~lagsplat.diagnose.reading.indistinguishable`, asked where the best reaches half ``min_delta_bic``, as the report's reading does)."""
    close = indistinguishable(ranking, 0.5 * min_ev)
    ev = {r["effect"]: _num(r.get("evidence", r.get("delta_bic"))) for r in ranking}
    return [_record(f"{close[0]} vs {other}", False,
                    f"the residual ranks them within {INDISTINGUISHABLE:g} of each other (evidence {ev[close[0]]:.1f} and {ev[other]:.1f}; "
                    "the lines on what tells the candidates apart say what each signature reads)", _pair_settle(close[0], other))
            for other in close[1:]]  # fmt: skip


def identifiability(dg: Mapping[str, Any], gap: Mapping[str, Any] | None = None) -> list[dict[str, Any]]:
    """Which quantities the recording determines and which it cannot, and what recording would settle each (paper §3.3, §5).

    Args:
        dg: ``report.json["diagnosis"]`` (:meth:`~lagsplat.diagnose.diagnosis.Diagnosis.to_dict`): its ``evidence``
            (``envelope``, ``decay_law``, ``frequency``, ``rest``), ``ranking`` and ``settings`` (``min_delta_bic``,
            ``n_segments``: the takes).
        gap: ``report.json["gap"]``, or ``None``: the held-out frames' frequency (``before.f_enc_hz``, ``f_sim_hz``,
            ``eps_freq``), read beside the training frames' and where fewer than one period was timed.

    Returns:
        Records ``{"quantity", "determined", "why", "settle_by"}``, in this order: natural frequency, damping level,
        damping form (and, on one take where a decay law is found, that law against a damping drifting in time), the
        frequency's dependence on amplitude against time, where the motion comes to rest (where the rest was read; the oscillation's centre is the model's) and each
        candidate the residual cannot tell from the best. ``why`` is one sentence with the numbers; ``settle_by`` the
        recording that would settle it, ``None`` where determined. Records with missing evidence read as not determined.

    Raises:
        Nothing for a well-formed record: missing or non-finite numbers are read as absent.
    """
    ev = dg.get("evidence") or {}
    fr, env = ev.get("frequency") or {}, ev.get("envelope") or {}
    min_ev = float((dg.get("settings") or {}).get("min_delta_bic", 10.0))
    takes, f = int((dg.get("settings") or {}).get("n_segments") or 1), _frequency_hz(fr, gap or {})
    out = [_natural_frequency(fr, gap or {}, f), _damping_level(env, f, takes), *_damping_form(ev, f, min_ev, takes), _amplitude_vs_time(fr, min_ev, takes, list(dg.get("ranking") or []))]
    rest = _rest(ev.get("rest") or {}, env, f, min_ev)
    return out + ([rest] if rest else []) + _pairs(list(dg.get("ranking") or []), min_ev)
