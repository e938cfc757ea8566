"""Candidates that depend on time, the input or a hidden mode: periodic force, drift, actuation delay, missing degree of freedom.

The table of features and coefficients, and where the frequency searches are
restricted, are in :mod:`lagsplat.diagnose.effects`, which lists these in
:data:`~lagsplat.diagnose.effects.EFFECTS`.
"""

from __future__ import annotations

import math

import numpy as np

from lagsplat.diagnose.effect_base import Effect, ratio
from lagsplat.diagnose.image_signature import unencoded_oscillation
from lagsplat.diagnose.signatures import MIN_TIMING_PERIODS, timing_drifts
from lagsplat.diagnose.spectrum import excluded_bands, frequency_allowed, longest_segment_s, residual_peaks

__all__ = ["PeriodicForceEffect", "DriftEffect", "ActuationDelayEffect", "MissingDofEffect", "peak_frequencies"]


def _driven_over_motion(force_rms: float, f_over_motion: float, scale: dict[str, float]) -> float:
    """The motion a force of rms ``force_rms`` at ``f_over_motion`` times the oscillation drives through the fitted spring
    off resonance (``force / (k |1 - r^2|)``, rms), over the rms of the recorded (unsmoothed) motion along the direction."""
    return ratio(force_rms, scale["k"] * abs(1.0 - f_over_motion**2) * scale["s_raw_rms"])


def _visible_motion(interpretation: dict, thresholds: dict, what: str, kind: str) -> tuple[bool, str]:
    """:meth:`Effect.practical` of an effect at its own frequency: its motion (``interpretation["driven_over_motion"]``)
    must reach ``min_periodic_response`` of the recorded one."""
    rel = interpretation.get("driven_over_motion", float("nan"))
    lo = thresholds.get("min_periodic_response", 0.01)
    if not (rel >= lo):
        return False, (f"{what} is {100 * rel:.2g} % of the recorded motion (rms), below {100 * lo:g} %: "
                       f"{kind} too small to change what the video shows")  # fmt: skip
    return True, ""


def peak_frequencies(res, r0, n: int) -> list[float]:
    """Candidate frequencies (Hz): ``n`` steps across one clip-frequency bin (``+-1 / T``) around each of the
    residual's 3 strongest allowed spectral peaks (:func:`residual_peaks`), those :func:`frequency_allowed` keeps."""
    peaks = residual_peaks(r0, res.segment, res.dt, 3, exclude=excluded_bands(res))
    T = longest_segment_s(res)
    return [float(f + k / T) for f in peaks for k in np.linspace(-1.0, 1.0, n) if frequency_allowed(res, f + k / T)]


class PeriodicForceEffect(Effect):
    """Unlogged periodic force: ``phi = (cos 2 pi f t, sin 2 pi f t)`` in clip time, coefficients ``a, b``.

    The frequency ``f`` is profiled around the residual's spectral peaks outside the
    model's own bands (:func:`~lagsplat.diagnose.spectrum.excluded_bands`), then refined to
    about ``0.01 / span`` (phase-locked over the clip). Practical only when the motion it
    drives off resonance reaches ``min_periodic_response`` of the recorded one (rms).
    """

    def grid(self, res, e, r0):
        """Frequencies within one clip-frequency bin of the residual's 3 strongest allowed peaks."""
        return [{"f_hz": f} for f in peak_frequencies(res, r0, 11)]

    def refine(self, res, e, best):
        """Frequencies within ``0.2 / T`` of the best one in steps of ``0.01 / span`` (phase-locked over the clip)."""
        # the phase is locked over the whole clip: resolve f to ~0.01 / (time span)
        span = float(np.ptp(res.t)) + res.dt
        T = longest_segment_s(res)
        return [{"f_hz": float(best["f_hz"] + k)} for k in np.arange(-0.2 / T, 0.2 / T + 1e-12, 0.01 / span) if frequency_allowed(res, best["f_hz"] + k)]

    def feature(self, res, e, params):
        """``cos, sin(2 pi f t)`` in clip time; coefficients ``a_cos, b_sin``."""
        w = 2 * math.pi * params["f_hz"]
        return (lambda st: np.stack([np.cos(w * st.t), np.sin(w * st.t)], 1)), ["a_cos", "b_sin"]

    def practical(self, interpretation, thresholds):
        """A force only when the motion it drives off resonance reaches ``min_periodic_response`` of the recorded one."""
        return _visible_motion(interpretation, thresholds, "the motion it drives off resonance", "a force")

    def interpret(self, coef, se, params, res, e, scale):
        """Frequency, amplitude and phase, and the motion it drives relative to the recorded one."""
        amp = float(np.hypot(coef[0], coef[1]))
        amp_se = float(np.sqrt((coef[0] * se[0]) ** 2 + (coef[1] * se[1]) ** 2) / max(amp, 1e-300))
        r = ratio(params["f_hz"], res.f_dominant_hz)
        return {
            "f_hz": params["f_hz"], "amplitude": amp, "amplitude_se": amp_se, "phase": float(math.atan2(-coef[1], coef[0])),
            "f_over_model": r,
            "amplitude_over_restoring": ratio(amp, scale["k"] * scale["s_rms"]),
            # linear response of the fitted spring off resonance (the model's own band is excluded):
            # amplitude / (k |1 - r^2|), as an rms, over the rms of the recorded (unsmoothed) motion along e
            "driven_over_motion": _driven_over_motion(amp / math.sqrt(2.0), r, scale),
            "text": f"an unlogged periodic force at {params['f_hz']:.3g} Hz ({r:.2f}x the "
            f"oscillation), amplitude {amp:.3g} +- {amp_se:.2g}, phase-locked over the clip",
        }  # fmt: skip


class DriftEffect(Effect):
    """Slow linear drift of stiffness and damping: ``phi = (-(t - t_bar)(s - s_bar), -(t - t_bar) sdot)``.

    Coefficients ``dk/dt, dc/dt`` (per second); reading: the relative change of each over
    the recorded span and which one dominates. The stiffness part must agree with the recorded timing
    (:meth:`practical`): a stiffness changing by ``dk/dt`` moves the frequency at a given amplitude by
    ``dk/dt / (2 k)`` per second, which the zero-crossing periods (no monotone chart moves them) show.
    """

    trend_in_time = True

    def feature(self, res, e, params):
        """``-(t - t_bar)(s - s_bar), -(t - t_bar) sdot``; coefficients ``dk_dt, dc_dt``."""
        s_bar = float(np.mean(res.q @ e))
        t_bar = float(np.mean(res.t))

        def phi(st):
            s, v = self.coords(st, e)
            dt = st.t - t_bar
            return np.stack([-dt * (s - s_bar), -dt * v], 1)

        return phi, ["dk_dt", "dc_dt"]

    def against_linearisation_allowed(self, evidence, thresholds):
        """Only where the periods change in time beyond any dependence on the amplitude with very strong evidence and by
        a physical amount (:func:`~lagsplat.diagnose.signatures.timing_drifts`): against the linearisation a drifting
        stiffness and a cubic one both tie the frequency to the decaying amplitude, and only the timing tells them apart."""
        return timing_drifts(evidence.get("frequency") or {}, thresholds)

    def signature_support(self, evidence):
        """A stiffness drift changes the oscillation's timing at a given amplitude (the frequency signature's
        ``support_time``; zero crossings, which no monotone chart moves); a damping drift changes the decay rate of
        the turning points in time (the envelope's ``accelerating`` support). Read from different features of the
        recording, the two add (:func:`~lagsplat.diagnose.signatures.signatures`)."""
        f = evidence.get("frequency") or {}
        env = evidence.get("envelope") or {}
        k_sup = max(0.0, float(f.get("support_time", 0.0)))
        c_sup = max(0.0, float((env.get("support") or {}).get("accelerating", 0.0)))
        parts = []
        if k_sup > 0:
            parts.append(f"the period-by-period frequency changes by {100 * f['relative_change_over_span']:+.1f} % over the recording, "
                         f"more than any dependence on the amplitude explains (evidence {k_sup:.1f})")  # fmt: skip
        if c_sup > 0:
            acc = env["accelerating"]
            parts.append(f"the decay rate of the turning points changes by {acc['rate_change_per_s2']:+.3g} /s per second "
                         f"(evidence {c_sup:.1f} over a constant-rate, linear or hyperbolic decay)")  # fmt: skip
        return k_sup + c_sup, "; ".join(parts)

    def practical(self, interpretation, thresholds):
        """Not where the recorded periods contradict the fitted stiffness change.

        The stiffness part predicts the frequency at a given amplitude to change by ``dk/dt / (2 k)``
        per second; the frequency signature measures that change (its time slope, fitted beside any
        dependence on the amplitude, with its standard error). Where the prediction reaches half
        ``min_cubic_shift`` over the recording and lies more than 3 standard errors from the measured
        slope, while the measured slope is not at least half of it with the same sign, the stiffness
        trend is the fitted model's own misfit on this take (e.g. a frequency that depends on the
        amplitude a little differently from the recording's), not a change of the recording.

        Nor where the fitted trend, linear about the middle of the span, takes the stiffness or the damping
        through zero within the recording by more than two standard errors of its rate
        (:func:`_through_zero`): a stiffness changing sign or a damping turning negative is no slow change of a
        stable oscillator but a misfit the time trend happens to follow (as on a realistic double pendulum without
        any effect cut to three periods; ``docs/experiments/code_comment_history.md``). This check needs no timing
        signature, so it also holds on short clips and on several latent dimensions.
        """
        through_zero = _through_zero(interpretation)
        if through_zero:
            return False, through_zero
        chk = interpretation.get("timing_check")
        if not chk:
            return True, ""
        pred, meas, se, span = chk["predicted_rel_per_s"], chk["measured_rel_per_s"], chk["measured_se_rel_per_s"], chk["span_s"]
        if abs(pred) * span < 0.5 * thresholds.get("min_cubic_shift", 0.03):
            return True, ""
        agrees = meas * pred > 0 and abs(meas) >= 0.5 * abs(pred)
        if agrees or abs(pred - meas) <= 3.0 * se:
            return True, ""
        return False, (
            f"the recorded periods change by {100 * meas * span:+.1f} +- {100 * se * span:.1f} % over the {span:.0f} s at a given "
            f"amplitude where this stiffness change predicts {100 * pred * span:+.1f} %: the trend is the model's misfit, not the recording's"
        )

    def interpret(self, coef, se, params, res, e, scale):
        """Relative change of stiffness and damping over the recorded span, which dominates, and the timing it predicts."""
        span = float(np.ptp(res.t))
        rk, rc = ratio(coef[0] * span, scale["k"]), ratio(coef[1] * span, scale["c"])
        zk, zc = abs(coef[0]) / max(se[0], 1e-300), abs(coef[1]) / max(se[1], 1e-300)
        which = "stiffness" if zk >= zc else "damping"
        return {
            "dk_dt": float(coef[0]), "dk_dt_se": float(se[0]), "dc_dt": float(coef[1]), "dc_dt_se": float(se[1]),
            "stiffness_change_over_clip": rk, "damping_change_over_clip": rc, "dominant": which,
            "t_bar": float(np.mean(res.t)), "s_bar": float(np.mean(res.q @ e)), "k_model": scale["k"], "c_model": scale["c"], "span_s": span,
            "timing_check": _timing_check(coef[0], scale["k"], span, res),
            "text": f"slow drift, mainly of the {which}: over the {span:.0f} s recorded the stiffness changes by "
            f"{100 * rk:+.1f} % (z = {zk:.1f}) and the damping by {100 * rc:+.0f} % (z = {zc:.1f})",
        }  # fmt: skip


def _through_zero(interpretation) -> str:
    """Why a drift's fitted trend takes the stiffness or the damping through zero within the span (``""`` if it does not).

    The trend ``k(t) = k + dk/dt (t - t_bar)`` is linear about the span's middle, so it reaches ``k - |dk/dt| span / 2``
    at one end; that end is below zero, with the rate shrunk by two standard errors, when
    ``(|dk/dt| - 2 se) span / 2 > k`` (the same for the damping ``c``).
    """
    span = float(interpretation.get("span_s", 0.0))
    for name, rate, se, base in (("stiffness", "dk_dt", "dk_dt_se", "k_model"), ("damping", "dc_dt", "dc_dt_se", "c_model")):
        r, e, b = float(interpretation.get(rate, 0.0)), float(interpretation.get(se, 0.0)), float(interpretation.get(base, 0.0))
        if b > 0 and (abs(r) - 2.0 * e) * span / 2.0 > b:
            return (f"this trend takes the {name} through zero within the {span:.1f} s recorded ({100 * r * span / b:+.0f} % over "
                    f"the span, linear about its middle): no slow change of a stable oscillator, the model's misfit")  # fmt: skip
    return ""


def _timing_check(dk_dt: float, k: float, span: float, res) -> dict[str, float] | None:
    """The frequency change per second a stiffness drift ``dk_dt`` predicts (``dk_dt / (2 k)``, relative) beside the one the
    recorded periods show at a given amplitude (the frequency signature's time slope and its s.e., relative to the mean
    frequency); ``None`` without a usable signature (fewer than :data:`~lagsplat.diagnose.signatures.MIN_TIMING_PERIODS` periods,
    or several latent dimensions, whose modes beat)."""
    fsig = res.meta.get("frequency_signature") or {}  # select_effect's evidence, on both regressions' residuals
    f0 = float(fsig.get("f_mean_hz", float("nan")))
    if res.d != 1 or fsig.get("n_periods", 0) < MIN_TIMING_PERIODS or not (f0 > 0) or "slope_time" not in fsig or not (k > 0):
        return None
    return {"predicted_rel_per_s": float(dk_dt / (2.0 * k)), "measured_rel_per_s": float(fsig["slope_time"]) / f0,
            "measured_se_rel_per_s": float(fsig["slope_time_se"]) / f0, "span_s": span}  # fmt: skip


class ActuationDelayEffect(Effect):
    """Actuation delay: ``phi = u(t - tau) - u(t)`` per input channel, a gain per channel.

    Applicable only with actuation; ``tau`` is profiled from half a frame to 0.5 s in half-frame steps.
    """

    def applicable(self, res):
        """Only with logged actuation."""
        return res.n_u > 0

    def grid(self, res, e, r0):
        """Delays from half a frame to about 0.5 s in half-frame steps."""
        n = int(round(0.5 / res.dt))
        return [{"tau_s": float(k * res.dt / 2)} for k in range(1, 2 * n + 1)]

    def feature(self, res, e, params):
        """``u(t - tau) - u(t)`` per input channel; a gain per channel."""
        tau = params["tau_s"]
        return (lambda st: st.u_at(st.t - tau) - st.u_at(st.t)), [f"gain_u{j + 1}" for j in range(res.n_u)]

    def interpret(self, coef, se, params, res, e, scale):
        """The delay and the delayed-input gains."""
        return {
            "tau_s": params["tau_s"], "gain": [float(c) for c in coef], "gain_se": [float(s) for s in se],
            "text": f"the logged input acts {params['tau_s'] * 1000:.0f} ms late (delayed-input gain "
            + ", ".join(f"{c:.3g} +- {s:.2g}" for c, s in zip(coef, se)) + ")",
        }  # fmt: skip


class MissingDofEffect(Effect):
    """A hidden lightly damped mode: ``exp(-l t') (cos 2 pi f t', sin 2 pi f t')`` per segment, ``l = 2 pi f zeta``.

    ``t'`` is the time since the segment's first kept sample; the frequency ``f`` (around
    the residual's peaks outside the model's bands) and ``zeta <= 0.05`` are profiled, and
    each segment has its own amplitude and phase. Remedy: one more latent dimension.
    """

    def grid(self, res, e, r0):
        """Frequencies around the residual's 3 strongest allowed peaks, damping ratios 0 to 0.04."""
        return [{"f_hz": f, "zeta": z} for f in peak_frequencies(res, r0, 9) for z in (0.0, 0.0025, 0.005, 0.01, 0.02, 0.04)]

    def refine(self, res, e, best):
        """Frequencies within ``0.25 / T`` and damping ratios around the best ones (``zeta <= 0.05``)."""
        T = longest_segment_s(res)
        z0 = best["zeta"]
        # a lightly damped mode (zeta <= 0.05): a residual that dies out within a few cycles is a transient, not a mode
        zs = sorted({min(0.05, max(0.0, z0 * f)) for f in (0.6, 0.8, 1.0, 1.25, 1.5)} | {max(0.0, z0 - 0.0025), min(0.05, z0 + 0.0025)})
        return [{"f_hz": float(best["f_hz"] + k), "zeta": float(z)} for k in np.linspace(-0.25 / T, 0.25 / T, 11) for z in zs if frequency_allowed(res, best["f_hz"] + k)]

    def feature(self, res, e, params):
        """A decaying cosine and sine per segment, from the segment's first kept sample; two amplitudes per segment."""
        w = 2 * math.pi * params["f_hz"]
        lam = params["zeta"] * w
        n_seg = res.n_segments

        def phi(st):
            tt = st.t - st.t[st.keep.start]
            env = np.exp(-lam * tt)
            out = np.zeros((len(st.t), 2 * n_seg))
            out[:, 2 * st.index] = env * np.cos(w * tt)
            out[:, 2 * st.index + 1] = env * np.sin(w * tt)
            return out

        return phi, [f"seg{k}_{c}" for k in range(n_seg) for c in ("cos", "sin")]

    def fitted_support(self, fit, res, thresholds):
        """The autoencoder's error oscillating at the mode's frequency beyond what the encoded state explains
        (:func:`~lagsplat.diagnose.image_signature.unencoded_oscillation`): part of the scene moves in a way the chart
        does not carry, which a periodic force on the encoded coordinate does not do.

        It tells a hidden mode from a force at the same frequency; it does not find one: counted only where the
        regression itself finds the mode (``delta_bic >= min_delta_bic``) and the image's evidence alone is very strong
        (``>= min_delta_bic``). Always recorded as ``interpretation["image_error_support"]`` where the chart has the error.
        """
        img = res.meta.get("image_error")
        if img is None:
            return 0.0, ""
        sup = unencoded_oscillation(img, float(fit.params["f_hz"]), res.f_dominant_hz)["support"]
        fit.interpretation["image_error_support"] = sup
        lo = thresholds.get("min_delta_bic", 10.0)
        if not (fit.delta_bic >= lo and sup >= lo):
            return 0.0, ""
        return sup, (f"the autoencoder's per-frame error oscillates at the mode's frequency beyond what the encoded state explains "
                     f"(evidence {sup:.0f}): part of the scene moves in a way the chart does not carry, which a force would not do")  # fmt: skip

    def practical(self, interpretation, thresholds):
        """A mode only when its motion in the chart reaches ``min_periodic_response`` of the recorded one (as a periodic force's)."""
        return _visible_motion(interpretation, thresholds, "the motion of the mode", "a mode")

    def interpret(self, coef, se, params, res, e, scale):
        """Frequency, damping ratio, the amplitude in each segment, and the mode's motion relative to the recorded one.

        The mode's force on the chart coordinate, ``a exp(-l t')`` per segment (rms over the residual's samples), moves it
        by ``a / (k |1 - r^2|)`` (``r`` the mode's frequency over the oscillation's), as a periodic force does.
        """
        a = np.hypot(coef[0::2], coef[1::2])
        lam = params["zeta"] * 2 * math.pi * params["f_hz"]
        env2 = [float(np.mean((a[st.index] * np.exp(-lam * (st.t - st.t[st.keep.start]))) ** 2)) for st in res.states]
        r = ratio(params["f_hz"], res.f_dominant_hz)
        return {
            "f_hz": params["f_hz"], "zeta": params["zeta"], "segment_amplitudes": a.tolist(),
            "f_over_model": r, "driven_over_motion": _driven_over_motion(math.sqrt(0.5 * float(np.mean(env2))), r, scale),
            "text": f"a hidden mode at {params['f_hz']:.3g} Hz ({ratio(params['f_hz'], res.f_dominant_hz):.2f}x the oscillation), "
            f"damping ratio ~{params['zeta']:.3g}, with its own amplitude and phase in each segment: a degree of freedom the "
            "latent chart does not carry (remedy: one more latent dimension)",
        }  # fmt: skip
