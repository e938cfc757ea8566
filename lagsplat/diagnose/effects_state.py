"""Candidates that depend on the state only: dry friction and quadratic drag (dissipative), end stop and cubic stiffness (conservative, in class).

The table of features and coefficients, and why the in-class ones are fitted
against the model's linearisation and must reach a physical size, are in
:mod:`lagsplat.diagnose.effects`, which lists these in :data:`~lagsplat.diagnose.effects.EFFECTS`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from lagsplat.diagnose.decay_law import LAW_NAMES, law_evidence
from lagsplat.diagnose.effect_base import Effect, ratio
from lagsplat.diagnose.signatures import MIN_TIMING_PERIODS, timing_drifts, turns_one_sided

__all__ = ["CoulombEffect", "QuadraticDragEffect", "EndStopEffect", "CubicStiffnessEffect"]


def _relu(x: np.ndarray) -> np.ndarray:
    return np.maximum(x, 0.0)


def _decay_support(evidence: dict, law: str, envelope: float, envelope_text: str) -> tuple[float, str]:
    """The decay read once: the turning points' envelope support (``envelope >= 0``, with its reading) or, where its
    evidence is the larger, the whole trajectory's decay law ``law`` (:func:`~lagsplat.diagnose.decay_law.decay_law`)."""
    whole = law_evidence(evidence.get("decay_law"), law)
    if whole > envelope:
        return whole, f"the whole trajectory decays as {LAW_NAMES[law]} makes it (evidence {whole:.1f} over a viscous decay)"
    return envelope, envelope_text if envelope > 0 else ""


class CoulombEffect(Effect):
    """Dry (Coulomb) friction: ``phi = -tanh(sdot / v_s)``, coefficient ``mu >= 0`` (generalized-force units).

    The smooth-sign velocity ``v_s`` is set, not fitted (:meth:`grid`). Reading: the level
    ``mu``, its share of the restoring force at the rms amplitude and the amplitude lost per
    cycle, ``4 mu / k`` (a linear envelope).
    """

    #: smooth-sign velocity ``v_s`` as a fraction of the rms speed along ``e``: set, not fitted (see :meth:`grid`)
    V_S_FRACTION = 0.02

    def grid(self, res, e, r0):
        """One value, ``v_s = 0.02`` rms speed: dry friction is sharp, and the residual cannot say otherwise.

        The residual is smoothed over ``sigma`` frames, in which the speed near a
        reversal sweeps a large part of its range, so the residual barely tells
        a sharp sign from a smooth one: on the blind suite's friction clips the BIC
        barely moves over ``v_s`` from 0.01 to 0.4 rms speed. Fitted anyway, ``v_s``
        went where the noise put it, and the refit with that near-viscous term
        decayed exponentially, worse than the model without it; with ``v_s`` set here
        it does not (measured on the blind suite: ``docs/experiments/diagnosis_history.md``,
        ``docs/experiments/code_comment_history.md``).
        """
        v = float(np.sqrt(np.mean((res.qdot @ e) ** 2)))
        return [{"v_s": self.V_S_FRACTION * v}]

    def feature(self, res, e, params):
        """``-tanh(sdot / v_s)`` along ``e``; one coefficient, ``mu``."""
        vs = params["v_s"]
        return (lambda st: -np.tanh(self.coords(st, e)[1] / vs)), ["mu"]

    def signature_support(self, evidence):
        """A linear envelope (the amplitude falls by ``4 mu / k`` per cycle) and a rest off the centre of the oscillation.

        The decay is read once: by the turning points or, where its evidence is the larger, by the whole
        trajectory (:func:`~lagsplat.diagnose.decay_law.decay_law`, dry friction over viscous damping).
        The decay and the rest are read from different parts of the recording (while it moves, once it
        has stopped), so their evidence adds.
        """
        env = (evidence.get("envelope") or {}).get("support") or {}
        rest = evidence.get("rest") or {}
        lin, off = max(0.0, float(env.get("linear", 0.0))), float(rest.get("support", 0.0))
        lin, decay = _decay_support(evidence, "dry", lin, f"the turning points fall linearly (evidence {lin:.1f} over an exponential decay)")
        parts = [decay] if decay else []
        if off > 0:
            parts.append(f"the motion stops {abs(rest['offset_over_noise']):.1f} noise levels off the centre of its oscillation "
                         f"at t = {rest['rest_time_s']:.2f} s (evidence {off:.1f})")
        return lin + off, "; ".join(parts)

    def interpret(self, coef, se, params, res, e, scale):
        """The friction level, its share of the restoring force at the rms amplitude and the amplitude lost per cycle."""
        mu = float(coef[0])
        return {
            "mu": mu, "mu_se": float(se[0]), "v_s": params["v_s"],
            "mu_over_restoring": ratio(mu, scale["k"] * scale["s_rms"]),
            "amplitude_loss_per_cycle": ratio(4 * mu, scale["k"]),
            "text": f"dry friction of level {mu:.3g} +- {se[0]:.2g} ({100 * ratio(mu, scale['k'] * scale['s_rms']):.1f} % of the "
            f"restoring force at the rms amplitude): a linear envelope losing {ratio(4 * mu, scale['k']):.3g} (latent units) per cycle",
        }  # fmt: skip


class QuadraticDragEffect(Effect):
    """Quadratic drag: ``phi = -|sdot| sdot``, coefficient ``c2 >= 0``.

    Reading: ``c2`` and the equivalent viscous damping at the rms speed
    (``8 / (3 pi) c2 V``, ``V`` the speed amplitude, sqrt 2 times the rms speed) over the model's own;
    the envelope decays hyperbolically.
    """

    def feature(self, res, e, params):
        """``-|sdot| sdot`` along ``e``; one coefficient, ``c2``."""
        def phi(st):
            v = self.coords(st, e)[1]
            return -np.abs(v) * v

        return phi, ["c2"]

    def signature_support(self, evidence):
        """A hyperbolic envelope: the decay rate grows with the amplitude (``1 / A`` falls linearly in time); read by the
        turning points or, where its evidence is the larger, by the whole trajectory
        (:func:`~lagsplat.diagnose.decay_law.decay_law`, quadratic drag over viscous damping)."""
        hyp = max(0.0, float(((evidence.get("envelope") or {}).get("support") or {}).get("hyperbolic", 0.0)))
        return _decay_support(evidence, "drag", hyp, f"the turning points fall hyperbolically (evidence {hyp:.1f} over an exponential decay)")

    def interpret(self, coef, se, params, res, e, scale):
        """``c2`` and its equivalent viscous damping at the speed amplitude, relative to the model's."""
        c2 = float(coef[0])
        eq = c2 * 8.0 / (3.0 * math.pi) * scale["sdot_rms"] * math.sqrt(2)  # equivalent viscous at the rms speed amplitude
        return {
            "c2": c2, "c2_se": float(se[0]),
            "equivalent_viscous_over_model": ratio(eq, scale["c"]),
            "text": f"quadratic drag c2 = {c2:.3g} +- {se[0]:.2g}: at the rms speed it equals "
            f"{ratio(eq, scale['c']):.2f}x the model's viscous damping; the envelope decays hyperbolically",
        }  # fmt: skip


class EndStopEffect(Effect):
    """One-sided end stop (penalty contact): ``phi = -side relu(side (s - s_stop))``, coefficient ``k_stop >= 0``.

    In class. The stop position ``s_stop`` (grid on quantiles of ``s``, then refined) and
    the side are profiled; position, stiffness and the share of samples in contact are read on
    the chart's own, unsmoothed positions (:attr:`~lagsplat.diagnose.residual_data.SegmentState.q_raw`).
    Practical only when ``k_stop`` is at least ``min_stop_stiffness_ratio`` times the spring's and
    the stop is touched on at most ``max_stop_contact_fraction`` of the samples. A stop limits the
    range of motion and is far stiffer than the spring, so the object spends a minority of its time
    on it, whether it sits at a gap beyond the rest position or at rest itself (a bouncing contact
    takes ``1 / (1 + sqrt(ratio))`` of the time at zero gap: under a quarter from about 9x; the true
    stops of the suites' clips and of the real bouncing cart are touched on fewer samples than that). A kink
    touched on more of the samples lies inside the range: a spring that is stiffer on one side (the
    measurements: ``docs/experiments/code_comment_history.md``).
    A rigid stop struck on every swing (the motion arrives at speed and reverses at a fixed position on
    the fitted side, losing energy: the signatures' ``impacts``, :mod:`lagsplat.diagnose.impacts`) spends no time past
    the stop at all; the penalty's kink then sits wherever the smoothed chart rounds the reversal off, and
    the share of samples past it says nothing: the stiffness and contact-share rules give way to the impacts,
    their evidence is the stop's whatever the regression's own ``Delta BIC`` (a smooth penalty fits a bounce
    poorly), and the reading names the stop's position and the restitution. With stops on both sides the
    energy goes twice a cycle and each side may see two impacts only: both sides' impacts count together
    (the signatures' ``both_sides``).
    """

    def grid(self, res, e, r0):
        """Stop positions at quantiles of the chart's own positions along ``e``, on either side."""
        s = res.q_raw @ e
        out = []
        for side, qs in ((1.0, (0.5, 0.6, 0.7, 0.8, 0.85, 0.9, 0.93, 0.96, 0.98)), (-1.0, (0.5, 0.4, 0.3, 0.2, 0.15, 0.1, 0.07, 0.04, 0.02))):
            for a in np.quantile(s, qs):
                out.append({"side": side, "s_stop": float(a)})
        return out

    def refine(self, res, e, best):
        """Stop positions within +-4 % of the range of ``s`` around the best one, same side."""
        s = res.q_raw @ e
        step = 0.01 * float(np.ptp(s))
        return [{"side": best["side"], "s_stop": float(best["s_stop"] + k * step)} for k in (-4, -3, -2, -1, 1, 2, 3, 4)]

    def feature(self, res, e, params):
        """``-side relu(side (s_raw - s_stop))`` on the chart's own positions; one coefficient, ``k_stop``."""
        side, a = params["side"], params["s_stop"]
        return (lambda st: -side * _relu(side * (st.q_raw @ e - a))), ["k_stop"]

    def fitted_support(self, fit, res, thresholds):
        """The motion turning around far more sharply on the stop's side than on the other (the signatures' ``turning``,
        :func:`~lagsplat.diagnose.signatures.signatures`): at least ``min_one_sided_turning`` times, with very strong
        evidence (``>= min_delta_bic``), where the residual's own fit prefers the stop to none (``delta_bic > 0``);
        or, where the motion strikes a stop on the fitted side (:func:`_struck`), the impacts' own evidence, whatever the
        regression's ``delta_bic`` (a smooth stiff term fits a bounce at the stop poorly, the reversals themselves do not).
        The same observation sets a cubic stiffness aside (:class:`CubicStiffnessEffect`)."""
        struck = fit.interpretation.get("impacts")  # :meth:`interpret`'s reading of the impacts on the fitted side
        if struck:  # the impacts are their own evidence: the smooth stop term of the regression may fit them poorly
            return struck["evidence"], (f"the motion strikes it on {struck['n_impacts']} of {struck['n_while_met']} swings and leaves at "
                                        f"{struck['restitution']:.2f} of its speed (evidence {struck['evidence']:.0f})")  # fmt: skip
        turn = (res.meta.get("signatures") or {}).get("turning") or {}
        if not turn or not fit.delta_bic > 0:
            return 0.0, ""
        side = fit.params["side"] * math.copysign(1.0, float(np.dot(fit.direction, turn["direction"])))
        if side != (1.0 if turn["sharper_side"] == "upper" else -1.0) or not turns_one_sided(turn, thresholds):
            return 0.0, ""
        sup = float(turn["support"])
        return sup, f"the motion turns around {turn['ratio']:.1f}x as sharply on the stop's side as on the other (evidence {sup:.0f})"

    def practical(self, interpretation, thresholds):
        """A stop when struck on the fitted side; else only when it is at least ``min_stop_stiffness_ratio`` times as
        stiff as the spring and touched on at most ``max_stop_contact_fraction`` of the samples (class docstring)."""
        if interpretation.get("impacts"):  # the motion strikes the stop: its reversals, not a smooth stiff term, tell it
            return True, ""
        ratio = interpretation.get("stiffness_ratio", float("nan"))
        lo = thresholds.get("min_stop_stiffness_ratio", 2.0)
        if not (ratio >= lo):
            return False, f"stop stiffness {ratio:.2g}x the spring's, below {lo:g}x: a gentle asymmetry of the spring, not a stop"
        frac = interpretation.get("fraction_in_contact", float("nan"))
        hi = thresholds.get("max_stop_contact_fraction", 0.25)
        if not (frac <= hi):
            return False, (f"{100 * frac:.0f} % of the samples past the kink, more than {100 * hi:g} %: the kink lies inside the range of "
                           f"motion, a spring {ratio:.2g}x stiffer on one side, not a stop at the end of the range")  # fmt: skip
        return True, ""

    def interpret(self, coef, se, params, res, e, scale):
        """Stop position and side, stiffness relative to the model's, share of samples in contact; where the motion
        strikes a stop on the fitted side (:func:`_struck`), the impacts: the stop's position and the restitution."""
        k = float(coef[0])
        s = res.q_raw @ e
        frac = float(np.mean(params["side"] * (s - params["s_stop"]) > 0))
        text = (f"one-sided stop at s = {params['s_stop']:.3g} ({'upper' if params['side'] > 0 else 'lower'} side, "
                f"{100 * frac:.0f} % of samples in contact), stiffness {k:.3g} +- {se[0]:.2g} = {ratio(k, scale['k']):.2g}x the model's")  # fmt: skip
        impacts = _struck(res, e, params["side"])
        if impacts:
            lo, hi = impacts["restitution_90"]
            where = "stops on both sides, this one" if impacts["both_sides"] else "a stop"
            text = (f"{where} struck on {impacts['n_impacts']} of {impacts['n_while_met']} swings at s = {impacts['s_stop']:.3g} "
                    f"({impacts['side']} side), restitution {impacts['restitution']:.2f} (90 % interval {lo:.2f}-{hi:.2f}"
                    f"{', over the impacts of both' if impacts['both_sides'] else ''}); " + text)  # fmt: skip
        return {
            "k_stop": k, "k_stop_se": float(se[0]), "s_stop": params["s_stop"], "side": params["side"],
            "stiffness_ratio": ratio(k, scale["k"]), "fraction_in_contact": frac, "impacts": impacts, "text": text,
        }  # fmt: skip


def _struck(res: Any, e: np.ndarray, side: float) -> dict[str, Any] | None:
    """The impacts of the signatures (:func:`~lagsplat.diagnose.impacts.impact_signature`) on the fitted stop's side,
    read along ``e``: ``{side, s_stop, n_impacts, n_while_met, restitution, restitution_90}``; ``None`` where the
    motion does not strike a stop there, or where the reversals lose no energy (the restitution's 90 % interval
    reaches 1): a spring ten times stiffer past a kink inside the range turns the motion around within a few frames
    too, elastically (a restitution close to 1 read on such charts), and the contact share tells it from a stop."""
    sig = (res.meta.get("signatures") or {}).get("impacts") or {}
    if not sig.get("stop_side"):
        return None
    sgn = math.copysign(1.0, float(np.dot(e, sig["direction"])))  # the signature's direction against the fit's
    both = sig.get("both_sides")
    fitted = "upper" if side * sgn > 0 else "lower"  # the fitted side, named in the signature's direction
    if not (fitted == sig["stop_side"] or both):
        return None
    d = sig[fitted]
    read = both or d  # stops on both sides: the restitution and the evidence of all the impacts
    if not read["restitution_90"][1] < 1.0:  # no energy lost at the reversal: a stiff spring turns it as fast (elastic)
        return None
    return {"side": "upper" if side > 0 else "lower", "s_stop": sgn * d["s_stop"], "n_impacts": d["n_impacts"],
            "n_while_met": d["n_while_met"], "restitution": read["restitution"], "restitution_90": read["restitution_90"],
            "evidence": read["evidence"], "both_sides": both is not None}  # fmt: skip


class CubicStiffnessEffect(Effect):
    """Hardening (``k3 > 0``) or softening (``k3 < 0``) stiffness: ``phi = -(s - s_bar)^3``.

    In class. Practical only when the Duffing frequency shift at the largest amplitude,
    ``3 k3 A^2 / (8 k)`` (Nayfeh & Mook 1979, ch. 4), reaches ``min_cubic_shift`` and the
    recorded zero-crossing periods shift the same way by at least half of that (a chart
    that stretches large excursions changes the waveform in ``q``, not the period), and
    only when those periods do not also change in time at a given amplitude (a drifting
    stiffness on a decaying oscillation ties frequency to amplitude as well). Like any odd
    force it turns the motion around alike on both sides: where one side turns at least
    ``min_one_sided_turning`` times as sharply as the other with very strong evidence
    (:func:`~lagsplat.diagnose.signatures.signatures`, ``turning``), the nonlinearity is
    one-sided (a stop), and a cubic is not claimed.
    """

    def feature(self, res, e, params):
        """``-(s - s_bar)^3`` along ``e``; one coefficient, ``k3``."""
        s_bar = float(np.mean(res.q @ e))
        return (lambda st: -((self.coords(st, e)[0] - s_bar) ** 3)), ["k3"]

    def practical(self, interpretation, thresholds):
        """A predicted frequency shift of ``min_cubic_shift`` at the largest amplitude, shown by the recorded periods, and periods
        that do not drift in time beyond what the amplitude explains (:func:`~lagsplat.diagnose.signatures.timing_drifts`:
        a drifting stiffness on a decaying oscillation also ties frequency to amplitude) (class docstring)."""
        pred = interpretation.get("relative_frequency_shift_at_amplitude", float("nan"))
        lo = thresholds.get("min_cubic_shift", 0.03)
        if not (abs(pred) >= lo):
            return False, f"frequency shift {100 * abs(pred):.1f} % at the largest amplitude, below {100 * lo:g} %"
        # A Duffing term shifts the period with amplitude; a chart that stretches large excursions
        # (q a nonlinear function of the physical coordinate) does not: zero-crossing periods are
        # chart-invariant. Accept only a shift the recording shows, with the sign of k3.
        meas = interpretation.get("measured_frequency_shift")
        if meas is not None and math.isfinite(meas) and not (meas * pred > 0 and abs(meas) >= 0.5 * lo):
            return False, (
                f"the recorded periods shift by {100 * meas:+.1f} % at the largest amplitude (frequency vs amplitude^2, "
                f"z = {interpretation.get('measured_frequency_z', float('nan')):.1f}) where this k3 predicts {100 * pred:+.1f} %: "
                "the anharmonic waveform in q comes from the chart, not from a stiffness"
            )
        fsig = interpretation.get("timing") or {}
        if timing_drifts(fsig, thresholds):
            return False, (
                f"the recorded periods change by {100 * fsig['relative_change_over_span']:+.1f} % in time beyond any dependence on the "
                f"amplitude (evidence {fsig['support_time']:.1f}): the stiffness changes with time, not with the excursion"
            )
        # a cubic, like any odd force, turns the motion around alike on both sides; one side turning far sharper is one-sided
        turn = interpretation.get("turning") or {}
        if turns_one_sided(turn, thresholds):
            return False, (
                f"the motion turns around {turn['ratio']:.1f}x as sharply on the {turn['sharper_side']} side as on the other "
                f"(evidence {turn['support']:.0f}): a one-sided nonlinearity such as a stop, not a cubic stiffness, which acts alike on both"
            )
        return True, ""

    def interpret(self, coef, se, params, res, e, scale):
        """``k3``, hardening or softening, the Duffing frequency shift at the largest amplitude and the one the recorded periods show
        (``None``, and the text says so, where fewer than :data:`~lagsplat.diagnose.signatures.MIN_TIMING_PERIODS` were recorded)."""
        k3 = float(coef[0])
        s = res.q @ e
        x = s - s.mean()
        A = float(np.quantile(np.abs(x), 0.99))
        # the linear stiffness without the part of the cubic that a straight-line fit absorbs
        k1 = scale["k"] - k3 * float(np.mean(x**4) / max(np.mean(x**2), 1e-300))
        shift = 3.0 * k3 * A * A / (8.0 * k1) if k1 > 0 else float("nan")
        fsig = res.meta.get("frequency_signature") or {}  # select_effect's evidence (chart-invariant periods)
        n_periods = int(fsig.get("n_periods", 0))
        meas = fsig.get("relative_shift_at_max_amplitude") if n_periods >= MIN_TIMING_PERIODS else None
        return {
            "k3": k3, "k3_se": float(se[0]), "kind": "hardening" if k3 > 0 else "softening",
            "relative_frequency_shift_at_amplitude": shift, "amplitude": A, "s_bar": float(s.mean()), "k_linear": k1,
            "measured_frequency_shift": None if meas is None else float(meas),
            "measured_frequency_z": None if meas is None else float(fsig["z_amp2"]),
            "timing": {k: fsig[k] for k in ("support_time", "relative_change_over_span") if k in fsig},
            "turning": {k: v for k, v in ((res.meta.get("signatures") or {}).get("turning") or {}).items() if k in ("ratio", "sharper_side", "support")},
            "text": f"{'hardening' if k3 > 0 else 'softening'} cubic stiffness k3 = {k3:.3g} +- {se[0]:.2g}: "
            f"frequency {'+' if shift >= 0 else ''}{100 * shift:.1f} % at amplitude {A:.3g} (Duffing, 3 k3 A^2 / 8 k); "
            "in the latent coordinate, where a chart that stretches or compresses large excursions looks the same"
            + ("" if meas is not None or not fsig else
               f"; not checked against the recorded periods ({n_periods} periods, {MIN_TIMING_PERIODS} needed), so on one decaying take "
               "a stiffness that drifts in time would read the same"),
        }  # fmt: skip
