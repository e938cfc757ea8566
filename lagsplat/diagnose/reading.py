"""What tells the candidate effects apart on one clip, in a physicist's words (the head of ``report.md``).

Reads the ``diagnosis`` record of ``report.json`` (:meth:`lagsplat.diagnose.diagnosis.Diagnosis.to_dict`):
the chart-invariant signatures of :func:`~lagsplat.diagnose.signatures.signatures` (the decay's shape,
the frequency against amplitude and time, where the motion comes to rest, the residual's spectrum)
and the ranking's evidence, and says which candidates the data cannot tell apart (paper §3.3, the
diagnosis; the physics of each signature is in :mod:`lagsplat.diagnose.effects`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from lagsplat.diagnose.decay_law import LAW_NAMES, LAWS, MIN_LOSS_PER_PERIOD, law_evidence
from lagsplat.diagnose.diagnosis import failed_rules

__all__ = ["distinguishing_lines", "not_significant_lines", "carried_nonlinearity_line", "indistinguishable", "INDISTINGUISHABLE", "STRONG_Z", "WEAK_Z", "CONFOUNDED"]

#: Evidence difference below which two candidates cannot be told apart ("not worth more than a bare mention", Kass & Raftery 1995)
INDISTINGUISHABLE = 2.0

#: |z| of a frequency slope that counts as a dependence (on amplitude or on time)
STRONG_Z = 3.0

#: |z| below :data:`STRONG_Z` from which a frequency slope is reported as a trend that is not conclusive (not as "none")
WEAK_Z = 2.0

#: |corr(A^2, t)| of the periods above which amplitude and time are one variable on the recording
CONFOUNDED = 0.9

_FORM = {"linear": "linear (dry friction)", "hyperbolic": "hyperbolic (quadratic drag)", "exponential": "exponential (viscous damping, what the model has)"}


def _num(x: Any) -> float:
    return float(x) if isinstance(x, (int, float)) and math.isfinite(x) else float("nan")


def _decay(env: Mapping[str, Any]) -> str:
    n, sup = int(env.get("n_turning_points") or 0), env.get("support") or {}
    if not env.get("best") or not sup or max(abs(_num(sup.get("linear"))), abs(_num(sup.get("hyperbolic")))) < INDISTINGUISHABLE:
        return (f"decay shape: {n} turning points cannot tell a linear (dry friction), a hyperbolic (quadratic drag) and an "
                "exponential (viscous) decay apart")  # fmt: skip
    best = env["best"]
    if best == "exponential":
        return f"decay shape: exponential (viscous damping, what the model has) over linear and hyperbolic ({n} turning points)"
    return f"decay shape: {_FORM[best]}, evidence {_num(sup.get(best)):.1f} over an exponential decay ({n} turning points)"


#: How each decay law takes the amplitude, as the report's decay line says it.
_LAW_SHAPE = {"dry": "faster, relative to the amplitude, as it shrinks", "drag": "faster at large amplitude"}


def _law(law: Mapping[str, Any], min_delta_bic: float = 10.0) -> str:
    """The whole trajectory's decay law (:func:`~lagsplat.diagnose.decay_law.decay_law`), where it was read."""
    if not law:
        return ""
    ev = {k: law_evidence(law, k, practical_only=False) for k in LAWS}
    best = max(ev, key=ev.get)
    if not ev[best] >= min_delta_bic:  # also where neither coefficient took its sign
        return f"decay over the whole trajectory: no law reads it better than viscous damping does (evidence below {min_delta_bic:g})"
    loss = law[best].get("loss_per_period")  # absent from records written before the size was read
    size = "" if loss is None else f"it alone takes {100 * float(loss):.2g} % of the amplitude per period"
    if not law[best].get("practical", True):  # read, but below the practical size (a record without the size counts as practical)
        return (f"decay over the whole trajectory: {LAW_NAMES[best]} reads it better than viscous damping (evidence {ev[best]:.1f}), but {size}, "
                f"below {100 * MIN_LOSS_PER_PERIOD:g} %: too small to count")  # fmt: skip
    size = size and "; " + size
    line = f"decay over the whole trajectory: {LAW_NAMES[best]} ({_LAW_SHAPE[best]}), evidence {ev[best]:.1f} over viscous damping{size}"
    if law.get("n_segments") == 1:  # one take: the amplitude falls with time, so a damping that changes in time decays alike
        line += (f"; on one take a damping that {'rises' if best == 'dry' else 'falls'} over the recording changes the decay alike "
                 "(a take released at another amplitude would tell them apart)")  # fmt: skip
    return line


def _frequency(fr: Mapping[str, Any], min_delta_bic: float = 10.0) -> list[str]:
    if "z_amp2" not in fr:
        return [f"frequency: {fr.get('n_periods', 0)} periods are too few to read it against amplitude and time"]
    za, zt = _num(fr["z_amp2"]), _num(fr["z_time"])
    if abs(za) >= STRONG_Z:
        amp = (f"frequency {'rises' if za > 0 else 'falls'} with the amplitude ({100 * _num(fr['relative_shift_at_max_amplitude']):+.1f} % at the "
               f"largest, z = {za:.1f}): a {'hardening spring or a stop' if za > 0 else 'softening restoring force'}")  # fmt: skip
    elif abs(za) >= WEAK_Z:
        amp = (f"frequency {'rises' if za > 0 else 'falls'} a little with the amplitude ({100 * _num(fr['relative_shift_at_max_amplitude']):+.1f} % "
               f"at the largest, z = {za:.1f}: not conclusive)")  # fmt: skip
    else:
        amp = f"frequency independent of the amplitude (z = {za:.1f})"
    if abs(zt) >= STRONG_Z:
        time = f"it drifts over the recording ({100 * _num(fr['relative_change_over_span']):+.1f} %, z = {zt:.1f})"
    elif abs(zt) >= WEAK_Z:
        time = f"a weak trend in time ({100 * _num(fr['relative_change_over_span']):+.1f} % over the recording, z = {zt:.1f}: not conclusive)"
    else:
        time = f"no drift in time (z = {zt:.1f})"
    lines = [f"{amp}; {time}"]
    corr, sup = _num(fr.get("corr_amp2_time")), _num(fr.get("support_time"))
    if abs(corr) >= CONFOUNDED and max(abs(za), abs(zt)) >= STRONG_Z:
        lines.append(
            f"amplitude and time: the amplitude falls steadily over this recording (corr(A^2, t) = {corr:.2f}), so a frequency "
            "that depends on the amplitude (cubic stiffness, a stop) and a stiffness that drifts in time change the periods alike; "
            + (f"the timing still separates them (a change in time at a given amplitude, evidence {sup:.1f})" if sup >= min_delta_bic else
               "they cannot be told apart here: a second take released at another amplitude would")
        )  # fmt: skip
    return lines


def _rest(rest: Mapping[str, Any]) -> str:
    if not rest:
        return ""
    if not rest.get("at_rest"):
        return "rest: the motion does not come to rest in these frames"
    z = abs(_num(rest.get("offset_over_noise")))
    where = "off the centre of its oscillation (dry friction sticks off-centre)" if rest.get("support", 0) > 0 else "at the centre of its oscillation"
    return f"rest: the motion stops at t = {_num(rest['rest_time_s']):.2f} s, {z:.1f} chart-noise levels {where}"


def _spectrum(sp: Mapping[str, Any]) -> str:
    if not sp:
        return ""
    extra = sp.get("unexplained_peaks_hz") or []
    if extra:
        return "residual spectrum: peaks the model lacks at " + ", ".join(f"{f:.3g}" for f in extra) + " Hz (a periodic force or a hidden mode)"
    return "residual spectrum: no peak away from the model's modes, the motion's frequency and their harmonics"


def _image(ranking: list[Mapping[str, Any]], min_delta_bic: float) -> str:
    """The autoencoder's per-frame error at a hidden mode's frequency, where the residual finds the mode
    (:meth:`~lagsplat.diagnose.effects_time.MissingDofEffect.fitted_support`)."""
    mode = next((r for r in ranking if r.get("effect") == "missing_dof"), None)
    it = (mode or {}).get("interpretation") or {}
    sup = _num(it.get("image_error_support"))
    if mode is None or not math.isfinite(sup) or not _num(mode.get("delta_bic")) >= min_delta_bic:
        return ""
    f = _num((mode.get("params") or {}).get("f_hz"))
    if sup >= min_delta_bic:
        return (f"image: the autoencoder's per-frame error oscillates at the hidden mode's {f:.3g} Hz beyond what the encoded state "
                f"explains (evidence {sup:.0f}): part of the scene moves in a way the chart does not carry, a mode rather than a force")
    return (f"image: the autoencoder's per-frame error shows no motion at {f:.3g} Hz that the chart does not carry (evidence {sup:.0f}): "
            "a hidden mode that moves the encoded body and a periodic force differ here only in their decay")


def indistinguishable(ranking: list[Mapping[str, Any]], min_evidence: float = 0.0) -> list[str]:
    """Names of the physical candidates whose evidence is within :data:`INDISTINGUISHABLE` of the best one's.

    Args:
        ranking: the ``ranking`` records (``effect``, ``delta_bic``, ``evidence`` when present, ``physical``).
        min_evidence: the best one must reach this for the question to arise (nothing is "told apart" from noise).

    Returns:
        The names, best first; empty when fewer than two.
    """
    ev = [(r["effect"], _num(r.get("evidence", r.get("delta_bic")))) for r in ranking if r.get("physical", True)]
    ev = [(n, e) for n, e in ev if math.isfinite(e)]
    if not ev:
        return []
    top = max(e for _, e in ev)
    if top < min_evidence:
        return []
    close = [n for n, e in sorted(ev, key=lambda x: -x[1]) if e >= top - INDISTINGUISHABLE]
    return close if len(close) > 1 else []


def distinguishing_lines(dg: Mapping[str, Any]) -> list[str]:
    """The markdown bullets of "What tells the candidates apart on this clip" for a ``diagnosis`` record.

    Args:
        dg: ``report.json["diagnosis"]``.

    Returns:
        Lines starting with ``"- "``: the decay shape (turning points, whole trajectory), the frequency against amplitude and time (and, on a
        recording whose amplitude falls steadily in time, whether the timing can still tell an
        amplitude-dependent stiffness from a drifting one), the rest, the residual spectrum, the image's
        error at a hidden mode's frequency (where the residual finds one), and the candidates the data
        cannot tell apart (if any).
    """
    ev = dg.get("evidence") or {}
    st = dg.get("settings") or {}
    lines = [_decay(ev.get("envelope") or {}), _law(ev.get("decay_law") or {}, float(st.get("min_delta_bic", 10.0))), *_frequency(ev.get("frequency") or {}, float(st.get("min_delta_bic", 10.0))),
             _rest(ev.get("rest") or {}), _spectrum(ev.get("spectrum") or {}),
             _image(dg.get("ranking") or [], float(st.get("min_delta_bic", 10.0)))]  # fmt: skip
    close = indistinguishable(dg.get("ranking") or [], 0.5 * float(st.get("min_delta_bic", 10.0)))
    if close:
        lines.append(f"the residual cannot tell {', '.join(close[:-1])} and {close[-1]} apart (evidence within {INDISTINGUISHABLE:g} of each other)")
    return ["- " + s for s in lines if s]


def _why_not(c: Mapping[str, Any], st: Mapping[str, Any]) -> list[str]:
    """The significance rules (:func:`~lagsplat.diagnose.diagnosis.failed_rules`) that a ranked candidate
    (``report.json`` record) fails, in words."""
    min_r2, min_cv = float(st.get("min_r2", 0.1)), float(st.get("min_cv_gain", 0.02))
    failed = failed_rules(bool(c.get("physical", True)), c.get("practical") is not False, _num(c.get("evidence", c.get("delta_bic"))),
                          _num(c.get("r2")), _num(c.get("cv_gain")), _num(c.get("signature_support", 0.0)),
                          float(st.get("min_delta_bic", 10.0)), min_r2, min_cv, _num(c.get("cv_gain_own")),
                          bool((c.get("interpretation") or {}).get("impacts")))  # fmt: skip
    below = (c.get("interpretation") or {}).get("below_practical_size")
    words = {
        "physical": "its coefficients have an unphysical sign",
        "practical": f"set aside by its physical check: {below}" if below else "set aside by its physical check (size, or the recorded timing)",
        "r2": f"it explains {_num(c.get('r2')):.2f} of the residual's variance (R2 needs {min_r2:g})",
        "cv_gain": f"it does not predict held-back blocks of the training frames (CV gain {_num(c.get('cv_gain')):.2f}, needs {min_cv:g}"
        + ("" if c.get("cv_gain_own") is None else f"; its own, with the in-class corrections held, {_num(c.get('cv_gain_own')):.2f}, must not lose")
        + ")",
    }
    return [words[r] for r in failed if r in words]


def not_significant_lines(dg: Mapping[str, Any], n: int = 3) -> list[str]:
    """Why the strongest candidates whose evidence passes the threshold are still not findings (markdown bullets).

    A reader who sees ``Delta BIC 470`` beside "significant: no" needs the rule that stopped it: an
    unphysical sign, the candidate's own physical check (:meth:`~lagsplat.diagnose.effect_base.Effect.practical`,
    with its reason: e.g. a cubic stiffness whose frequency shift at the largest amplitude is under
    ``min_cubic_shift``, or that the recorded periods contradict), too little of
    the residual explained, or no blocked cross-validation gain (:func:`~lagsplat.diagnose.select.decide`).

    Args:
        dg: ``report.json["diagnosis"]``.
        n: at most this many candidates, in ranking order.

    Returns:
        Lines starting with ``"- "`` (empty when no such candidate).
    """
    st = dg.get("settings") or {}
    min_ev = float(st.get("min_delta_bic", 10.0))
    out = []
    for c in dg.get("ranking") or []:
        ev = _num(c.get("evidence", c.get("delta_bic")))
        if c.get("significant") or not ev >= min_ev:
            continue
        why = _why_not(c, st)
        if why:
            out.append(f"- {c['effect']} (evidence {ev:.1f}): " + "; ".join(why))
        if len(out) >= n:
            break
    return out


def carried_nonlinearity_line(dg: Mapping[str, Any], max_excess: float = 2.0) -> str:
    """For a "nothing significant" verdict: the restoring force's nonlinearity that the identified model already carries.

    A learned potential can absorb a hardening spring (or a pendulum's softening): the model then
    reproduces the clip, the residual sits at the chart-noise level and no candidate is significant, yet
    the recorded periods still show the physics. Where the frequency signature moves with the amplitude
    with strong evidence (``|z| >= STRONG_Z``) and by at least ``min_cubic_shift`` at the largest
    amplitude, and the residual left is within ``max_excess`` times the chart-noise variance, one line
    says so (and, on one steady decay whose timing cannot separate them, that a stiffness drifting in
    time would look the same).

    Args:
        dg: ``report.json["diagnosis"]``.
        max_excess: largest residual / chart-noise variance at which the model counts as reproducing the clip.

    Returns:
        The line (no bullet), or ``""``.
    """
    fr = (dg.get("evidence") or {}).get("frequency") or {}
    st, null = dg.get("settings") or {}, dg.get("null") or {}
    za, shift = _num(fr.get("z_amp2")), _num(fr.get("relative_shift_at_max_amplitude"))
    excess = _num(null.get("excess_over_noise"))
    if not (abs(za) >= STRONG_Z and abs(shift) >= float(st.get("min_cubic_shift", 0.03)) and excess <= max_excess):
        return ""
    kind = "hardening" if shift > 0 else "softening"
    line = (f"the recorded frequency {'rises' if shift > 0 else 'falls'} with the amplitude ({100 * shift:+.1f} % at the largest, z = {za:.1f}): "
            f"a {kind} restoring force that the identified model already carries (its residual is {excess:.2g} x the chart noise), not a missing effect")  # fmt: skip
    if abs(_num(fr.get("corr_amp2_time"))) >= CONFOUNDED and not _num(fr.get("support_time")) >= float(st.get("min_delta_bic", 10.0)):
        line += "; on this steady decay a stiffness drifting in time would change the periods alike"
    return line
