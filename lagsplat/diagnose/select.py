"""Which unmodelled effect explains the residual: fit, rank, test, and collect the evidence.

Every candidate of :mod:`lagsplat.diagnose.effects` is fitted to the residual
generalized force ``r`` of :mod:`lagsplat.diagnose.residual` by linear least
squares in its coefficients, profiled over a grid of its few nonlinear
parameters (and, for ``d > 1``, over latent directions).

Nuisance terms
--------------
A fitted model that misses an effect compensates for it with what it has: a
Coulomb friction shows as extra viscous damping, a hardening spring as extra
stiffness. Each fit therefore includes *model-class* terms, and a candidate is
judged by what it explains *beyond* them (the null hypothesis "nothing
significant" is the nuisance fit alone). Two regressions share the work:

* **out-of-class** candidates (friction, drag, periodic force, drift, delay,
  missing DOF), which no setting of the Lagrangian can produce, are fitted to
  the residual of the *fitted model*, smoothed 1.5x wider than the in-class
  one (:attr:`Residual.wide <lagsplat.diagnose.residual_data.Residual.wide>`, see
  "Band of the out-of-class regression" below). The nuisance is linear in the state,
  ``r ~ dK q + dC qdot + f_0 (+ dB u)`` (free ``[d,d]`` matrices, one offset),
  plus the in-class corrections a convex potential, a position-dependent
  inertia and the input map ``b(q)`` could still make (centred ``q`` monomials
  of degree 2 and 3, also 4 and 5 for one coordinate; ``qdot_i qdot_j`` and ``q_k qdot_i qdot_j``; ``u_j q_i``),
  so that a model learned slightly wrong within its own class (or a chart
  that is a nonlinear function of the physical coordinate) is not taken for
  an effect it lacks (a drift, whose stiffness part a potential can partly
  follow on a decaying oscillation, is fitted in both regressions and keeps
  the better, :attr:`~lagsplat.diagnose.effect_base.Effect.also_in_class`);
* **in-class** candidates (:attr:`~lagsplat.diagnose.effect_base.Effect.in_class`:
  cubic stiffness, end stop), which a convex potential can partly absorb, are
  fitted to the residual of the model's *linearisation* on the data (its
  force minus its least-squares fit by the linear nuisance, added back to
  ``r``), with the linear and inertia nuisance: the effect is then seen in full,
  whether the model absorbed part of it or mis-learned it. They must also
  reach a physical size (:meth:`~lagsplat.diagnose.effect_base.Effect.practical`).

Residuals are weighted by the per-coordinate noise level (:attr:`Residual.noise_r <lagsplat.diagnose.residual_data.Residual.noise_r>`).

Band of the out-of-class regression
-----------------------------------
The Lagrangian class of the paper dissipates only through the Rayleigh
function ``1/2 qdot^T C(q) qdot`` (§3.3, "Dissipation"); what falls outside
(§5, "Limitations") and is in the library beyond it is mostly *slow*. A
quadratic drag ``-c2 |qdot| qdot`` or a dry friction is, at one amplitude,
almost a viscous damping (``|sin| sin`` is 98 % correlated with ``sin``): the
model's fitted ``C`` takes the mean, and what is left is the dependence of
the decay rate on the amplitude (the envelope is hyperbolic or linear, not
exponential), a modulation of the fundamental over the recording. At the
default smoothing (``period / 12``) the twice-differentiated chart noise peaks
near the 3rd harmonic and dominates the residual's variance, so ``R2``,
``Delta BIC`` and the CV gain of such an effect are diluted by noise where it
has no power. Out-of-class candidates are therefore fitted to the residual at
``1.5 x`` the smoothing (``period / 8``: noise variance 7.6x lower, the
fundamental still at 73 %), while the in-class candidates, whose signature is
the waveform (an end stop's one-sided spike, a Duffing 3rd harmonic), keep
the sharp residual. Both regressions keep their own null, noise level and
sample spacing, and the ranking compares their ``Delta BIC``. The reported
``null`` (``excess_over_noise``, ``unexplained``, the nuisance corrections) is
that of the sharp residual, as the localisation reads it; ``null["out_of_class"]``
is the null of the wide regression. On the blind suite's quadratic-drag pendulums
(``benchmarks/diagnosis.py``), whose drag causes most of the energy loss per cycle,
the drag is missed at the default smoothing and found at the wider one (the
measurement: ``docs/experiments/code_comment_history.md``).

Ranking and significance
------------------------
Candidates are ranked by the Bayesian information criterion (Schwarz 1978)
with a Gaussian likelihood of unknown variance,

    BIC = N_eff log(SSR / N) + k log N_eff,   N_eff = N / spacing,

``k`` counting the linear coefficients, the profiled nonlinear parameters and
the direction; ``spacing`` (2 sigma frames) accounts for the correlation the
smoothing puts between neighbouring residual samples. A candidate *wins* only
if it is physical (sign-constrained coefficients are fitted by non-negative
least squares, :func:`scipy.optimize.nnls`), of physical size (in-class
candidates) and passes all of

* ``Delta BIC = BIC_null - BIC >= min_delta_bic`` (10: "very strong" evidence,
  Kass & Raftery, JASA 90, 1995),
* ``R2 = 1 - SSR / SSR_null >= min_r2``: it explains a noticeable share of what
  the model leaves (effect size, so that a long clean clip does not promote a
  negligible misfit),
* a blocked cross-validation gain ``1 - CV_SSE / CV_SSE_null >= min_cv_gain``
  (contiguous blocks of about two periods, shorter on a short clip so that
  there are at least three, ``n_folds`` interleaved folds; the nonlinear
  parameters are the ones chosen on all data). A residual too short for two
  folds has no CV gain (``nan``, ``settings["cv_folds"] < 2``): nothing is
  significant and the report says why.

On one steady decay (amplitude and time one variable) a drift that the evidence cannot tell from a
law of the state is ranked behind it (:func:`state_laws_first`): a time dependence is claimed only
where the recording shows one beyond what the amplitude explains.

Otherwise the verdict is ``"none"`` ("nothing significant"). With
``max_effects > 1`` the search is repeated with the winners' features added
to the nuisance (greedy forward selection).

Evidence
--------
:func:`~lagsplat.diagnose.signatures.signatures` reads the physical signatures off the trajectory: the
envelope of the free decay (linear: dry friction; exponential: viscous;
hyperbolic: quadratic drag), the dependence of the period-by-period frequency on
amplitude (Duffing: hardening / softening, end stop) and on time (drift), where
the motion comes to rest (off the centre of the oscillation: dry friction), and
the residual's spectral peaks against the model's modal frequencies (periodic
force, missing degree of freedom).

The envelope and the rest count as evidence the way a physicist reads a decay:
each candidate says how much its own signature is present
(:meth:`~lagsplat.diagnose.effect_base.Effect.signature_support`, on the ``Delta BIC``
scale: the turning points' information criterion of a linear or hyperbolic
envelope over the exponential one, and ``z^2 - log N`` of an off-centre rest),
and that support is added to the candidate's ``Delta BIC`` (its *evidence*) for
the ranking and the significance rule. The turning points are a few numbers
read off the trajectory, not the residual force the regression fits, so a
near-resonant periodic force that mimics a linear decay in the residual gains
nothing from them. A signature that alone reaches ``min_delta_bic`` replaces
the cross-validation's positive gain (it must merely not lose, judged with the in-class
corrections held at their fit on the whole take, so that what is judged is the candidate's own
coefficients and not a quintic refitted on smaller amplitudes and extrapolated:
:meth:`~lagsplat.diagnose.regression.Regression.cv_sse_own`), and its effect
is not overruled by a rival's refit (:func:`~lagsplat.diagnose.refit_choice.choose_by_refit`).

Steps
-----
:func:`select_effect` runs them in order: the regressions
(:mod:`lagsplat.diagnose.regression`), then per round the *fit*
(:func:`~lagsplat.diagnose.candidates.fit_candidates`), the *rank*
(:func:`rank_candidates`: order by ``Delta BIC``, cross-validate where it can
matter) and the *decide* step (:func:`decide`: the significance rule); the
result is a :class:`~lagsplat.diagnose.diagnosis.Diagnosis`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from lagsplat.diagnose.candidates import candidate_design, fit_candidates
from lagsplat.diagnose.diagnosis import CandidateFit, Diagnosis, failed_rules
from lagsplat.diagnose.effect_base import Effect
from lagsplat.diagnose.effects import EFFECTS, get_effect
from lagsplat.diagnose.reading import CONFOUNDED, INDISTINGUISHABLE
from lagsplat.diagnose.regression import Regression, blocked_folds, linear_features, n_cv_folds
from lagsplat.diagnose.residual_data import Residual
from lagsplat.diagnose.signatures import directions, signatures

__all__ = ["select_effect", "rank_candidates", "state_laws_first", "decide", "signature_confirmed"]


def select_effect(
    res: Residual,
    candidates: Sequence[str] | None = None,
    *,
    min_delta_bic: float = 10.0,
    min_r2: float = 0.1,
    min_cv_gain: float = 0.02,
    min_cubic_shift: float = 0.03,
    min_stop_stiffness_ratio: float = 2.0,
    max_stop_contact_fraction: float = 0.25,
    min_one_sided_turning: float = 2.0,
    min_periodic_response: float = 0.01,
    max_effects: int = 1,
    n_folds: int = 5,
    block_s: float | None = None,
    model_freqs_hz: Sequence[float] | None = None,
    unexplained_excess: float = 4.0,
) -> Diagnosis:
    """Fit every candidate effect to the residual, rank them and decide (see the module docstring).

    Two regressions share the work:

    * out-of-class candidates (friction, drag, periodic force, drift, delay,
      missing DOF) are fitted to the residual of the *fitted model*, at the wider
      smoothing of :attr:`Residual.wide <lagsplat.diagnose.residual_data.Residual.wide>`
      when it is there (see "Band of the out-of-class regression" in the module
      docstring), with the linear nuisance plus the in-class corrections (potential: centred ``q``
      monomials of degree 2 and 3, also 4 and 5 for one coordinate; inertia: ``qdot qdot`` and ``q qdot qdot``;
      input map: ``u q``), so that a model learned slightly wrong within its
      own class is not mistaken for an effect it lacks;
    * in-class candidates (:attr:`~lagsplat.diagnose.effect_base.Effect.in_class`: cubic stiffness, end stop),
      which a convex potential can partly absorb, are fitted to the residual of
      the model's *linearisation* (the model's force minus its regression on
      the linear nuisance, added back), with the linear and inertia nuisance;
      they must also reach a physical size (``min_cubic_shift``: relative
      frequency shift at the largest amplitude; ``min_stop_stiffness_ratio``:
      stop stiffness over the spring's; ``max_stop_contact_fraction``: share of
      the samples in contact, since a stop limits the range and a kink inside it
      is a bilinear spring; ``min_one_sided_turning``: a cubic stiffness is not
      claimed where one side turns around that many times as sharply as the
      other, a one-sided nonlinearity). A cubic stiffness must moreover show in
      the recorded *timing*: the frequency-vs-amplitude^2 shift of the evidence
      (zero-crossing periods, which no monotone chart changes) must have the
      sign of ``k3`` and at least half the practical size, since a chart that
      stretches large excursions makes an isochronous oscillation look
      anharmonic in ``q`` but leaves its period alone. A periodic force (and a
      hidden mode) must drive a motion of at least ``min_periodic_response``
      (1 %) of the recorded one: coherent over the whole clip, a far smaller
      one is still significant, but changes nothing the video shows.

    Args:
        res: the residual (:func:`~lagsplat.diagnose.residual.residual_force`), normally
            on training frames only, so that held-out frames stay untouched for the gap;
            its :attr:`~lagsplat.diagnose.residual_data.Residual.wide` (if any) is the one the
            out-of-class candidates are fitted to.
        candidates: names to test (default: every applicable one of
            :data:`~lagsplat.diagnose.effects.EFFECTS`).
        min_delta_bic, min_r2, min_cv_gain: the statistical significance rule.
        min_cubic_shift, min_stop_stiffness_ratio, max_stop_contact_fraction, min_one_sided_turning: physical size
            and shape of in-class effects.
        min_periodic_response: physical size of a periodic force or a hidden mode: the rms motion it drives
            off resonance (``amplitude / (k |1 - (f / f_motion)^2|) / sqrt 2``) over the rms of
            the recorded motion along its direction.
        max_effects: how many effects greedy forward selection may accept.
        n_folds: folds of the blocked cross-validation.
        block_s: cross-validation block length, s (default two dominant periods).
        model_freqs_hz: the model's modal frequencies (excluded, with their harmonics and
            combination tones, from the periodic-force and hidden-mode search; spectrum evidence).
        unexplained_excess: ``null["unexplained"]`` (and a ``warning``) is set when the
            residual left after the nuisance and the accepted effects exceeds this many
            times the chart-noise variance.

    Returns:
        The :class:`~lagsplat.diagnose.diagnosis.Diagnosis`.

    Raises:
        KeyError: on an unknown candidate name.
        ValueError: if the residual has too few samples for the nuisance fit.
    """
    wide = res.wide if res.wide is not None and res.wide.n > 2 * (2 * res.d + 1 + res.n_u + 9) + 4 else res
    if model_freqs_hz is not None:
        res.meta["model_freqs_hz"] = [float(f) for f in model_freqs_hz]
        wide.meta["model_freqs_hz"] = [float(f) for f in model_freqs_hz]
    effs = [get_effect(c) for c in candidates] if candidates is not None else list(EFFECTS)
    effs = [e for e in effs if e.applicable(res)]
    thresholds = {"min_cubic_shift": min_cubic_shift, "min_stop_stiffness_ratio": min_stop_stiffness_ratio,
                  "max_stop_contact_fraction": max_stop_contact_fraction, "min_one_sided_turning": min_one_sided_turning,
                  "min_periodic_response": min_periodic_response, "min_delta_bic": min_delta_bic}  # fmt: skip
    rule = {"min_delta_bic": min_delta_bic, "min_r2": min_r2, "min_cv_gain": min_cv_gain}
    # the chart-invariant signatures, read before the fits: a cubic stiffness must also show in the timing
    ev = signatures(res, model_freqs_hz=model_freqs_hz)
    res.meta["frequency_signature"] = wide.meta["frequency_signature"] = ev["frequency"]
    res.meta["signatures"] = wide.meta["signatures"] = ev  # read by the candidates' signature_support
    probs, prob_null, prob_model = _regressions(res, wide, n_folds, block_s)
    dirs = {k: directions(p.res) for k, p in probs.items()}
    nuisance, null = _null_summary(res, wide, probs, prob_null)
    accepted, ranking = _forward_selection(effs, probs, prob_null, prob_model, dirs, res.d - 1, thresholds, rule, max_effects)
    _unexplained(null, prob_null, bool(accepted), unexplained_excess)
    settings = {
        **rule, **thresholds, "max_effects": max_effects,
        "n_folds": n_folds, "cv_folds": n_cv_folds(probs[True].folds), "candidates": [e.name for e in effs], "sigma_frames": res.sigma, "spacing": res.spacing,
        "n_samples": res.n, "n_segments": res.n_segments, "n_directions": len(dirs[True]),
        "sigma_frames_out_of_class": wide.sigma, "spacing_out_of_class": wide.spacing, "n_samples_out_of_class": wide.n,
    }  # fmt: skip
    return Diagnosis(accepted[0].effect if accepted else "none", accepted, ranking, null, ev, nuisance, settings)


def _forward_selection(
    effs: list[Effect], probs: dict[bool, Regression], prob_null: Regression, prob_model: Regression, dirs: dict[bool, list[np.ndarray]],
    extra_k: int, thresholds: dict[str, float], rule: dict[str, float], max_effects: int,
) -> tuple[list[CandidateFit], list[CandidateFit]]:
    """Greedy forward selection: fit, rank and decide per round; a winner's columns join every nuisance. ``(accepted, first-round ranking)``."""
    accepted: list[CandidateFit] = []
    ranking: list[CandidateFit] = []
    remaining = list(effs)
    for round_ in range(max(1, int(max_effects))):
        fits = fit_candidates(remaining, probs, prob_model, dirs, extra_k, thresholds)
        fits = rank_candidates(fits, probs, rule["min_delta_bic"], rule["min_r2"])
        win = decide(fits, **rule)
        if round_ == 0:
            ranking = fits
        if win is None:
            break
        accepted.append(win)
        for prob in {id(p): p for p in (*probs.values(), prob_null)}.values():
            prob.add_nuisance(win.design if prob is probs[win.against_linearisation] else candidate_design(prob, win))
        remaining = [e for e in remaining if e.name != win.effect]
        if not remaining:
            break
    return accepted, ranking


def rank_candidates(fits: list[CandidateFit], probs: dict[bool, Regression], min_delta_bic: float, min_r2: float) -> list[CandidateFit]:
    """Order the fits by decreasing evidence and cross-validate where it can matter (the *rank* step).

    The evidence is ``Delta BIC`` plus the signatures' support (:attr:`CandidateFit.evidence
    <lagsplat.diagnose.diagnosis.CandidateFit.evidence>`; module docstring, "Evidence"). The blocked
    cross-validation gain is the costly part: it is computed for the top 3 and for every physical fit
    whose evidence passes ``min_delta_bic`` and whose ``R2`` passes ``min_r2``; the others keep
    ``cv_gain = 0`` (they cannot be significant).

    Args:
        fits: from :func:`~lagsplat.diagnose.candidates.fit_candidates`; sorted in place.
        probs: ``{in_class: regression}`` the fits were made in.
        min_delta_bic, min_r2: the part of the significance rule that decides whether CV is needed.

    Returns:
        ``fits`` (the same list), best first, with ``cv_gain`` set; on one steady decay a drift the evidence
        cannot tell from a law of the state is behind it (:func:`state_laws_first`).
    """
    fits.sort(key=lambda f: f.evidence, reverse=True)
    cv_ref: dict[bool, float] = {}
    cv_own_ref: dict[bool, float] = {}
    for i, fit in enumerate(fits):
        if not (i < 3 or (fit.physical and fit.evidence >= min_delta_bic and fit.r2 >= min_r2)):
            continue
        eff = get_effect(fit.effect)
        lin = fit.against_linearisation
        prob = probs[lin]
        if lin not in cv_ref:
            cv_ref[lin] = prob.cv_sse(None, False)
        fit.cv_gain = 1.0 - prob.cv_sse(fit.design, eff.positive) / max(cv_ref[lin], 1e-300)
        if fit.signature_support >= min_delta_bic:
            if lin not in cv_own_ref:
                cv_own_ref[lin] = prob.cv_sse_own(None, False)
            fit.cv_gain_own = 1.0 - prob.cv_sse_own(fit.design, eff.positive) / max(cv_own_ref[lin], 1e-300)
    return state_laws_first(fits, probs[True].res.meta.get("frequency_signature") or {})


def state_laws_first(fits: list[CandidateFit], frequency: dict[str, Any]) -> list[CandidateFit]:
    """On one steady decay, a time-dependent candidate goes behind a law of the state it cannot be told from.

    A drift's signature is a change in time *independently of the amplitude*. Where the amplitude falls
    steadily (``|corr(A^2, t)| >= CONFOUNDED`` in the frequency signature: one freely decaying take), a
    damping or stiffness drifting in time fits as a law of the state does (dry friction's decay rate rises
    as the amplitude falls), and the time-independent law is the reading: a fit of a
    :attr:`~lagsplat.diagnose.effect_base.Effect.trend_in_time` effect whose evidence exceeds a physical
    dissipative or conservative rival's by at most ``INDISTINGUISHABLE`` goes behind the last such rival
    (``interpretation["behind"]`` names it; evidence values unchanged, and the report names the pair).

    Args:
        fits: ranked fits, best first (reordered in place).
        frequency: the frequency signature (its ``corr_amp2_time``; absent: nothing moves).

    Returns:
        ``fits``.
    """
    corr = frequency.get("corr_amp2_time")
    if corr is None or not abs(float(corr)) >= CONFOUNDED:
        return fits
    for fit in [f for f in fits if get_effect(f.effect).trend_in_time]:
        i = fits.index(fit)
        close = [j for j in range(i + 1, len(fits)) if fits[j].physical and get_effect(fits[j].effect).kind in ("dissipative", "conservative")
                 and fit.evidence - fits[j].evidence <= INDISTINGUISHABLE]  # fmt: skip
        if close:
            fits.insert(close[-1], fits.pop(i))
            fit.interpretation["behind"] = (f"{fits[close[-1] - 1].effect}: one steady decay cannot tell a change in time from a "
                                            f"dependence on the amplitude (corr(A^2, t) = {float(corr):.2f}; evidence within {INDISTINGUISHABLE:g})")  # fmt: skip
    return fits


def decide(fits: Sequence[CandidateFit], min_delta_bic: float, min_r2: float, min_cv_gain: float) -> CandidateFit | None:
    """Mark the significant fits and return the winner, the best significant one (the *decide* step).

    A fit is significant when it is physical, of physical size and passes ``evidence >= min_delta_bic``
    (``Delta BIC`` plus the signatures' support), ``R2 >= min_r2`` and ``cv_gain >= min_cv_gain``
    (module docstring, "Ranking and significance"). A fit whose signatures alone reach
    ``min_delta_bic`` (:func:`signature_confirmed`) has been checked on evidence the regression did
    not use: its own cross-validation need only not lose (``cv_gain_own >= 0``, the in-class corrections
    held at their fit on the whole take, or undefined on a clip too short for two folds).

    Args:
        fits: ranked fits (:func:`rank_candidates`); their ``significant`` flag is set.

    Returns:
        The first significant fit, or ``None`` (nothing significant).
    """
    for fit in fits:
        fit.significant = not failed_rules(fit.physical, fit.practical, fit.evidence, fit.r2, fit.cv_gain, fit.signature_support,
                                           min_delta_bic, min_r2, min_cv_gain, fit.cv_gain_own,
                                           bool(fit.interpretation.get("impacts")))  # fmt: skip
    return next((f for f in fits if f.significant), None)


def signature_confirmed(fit: CandidateFit, min_delta_bic: float = 10.0) -> bool:
    """Whether the chart-invariant signatures alone give ``fit`` very strong evidence (``signature_support >= min_delta_bic``)."""
    return bool(fit.signature_support >= min_delta_bic)


def _regressions(res: Residual, wide: Residual, n_folds: int, block_s: float | None) -> tuple[dict[bool, Regression], Regression, Regression]:
    """The regressions of :func:`select_effect`: ``({in_class: regression}, null regression, model regression)``.

    Raises:
        ValueError: if the residual has too few samples for the nuisance fit.
    """
    folds = blocked_folds(res, n_folds, block_s)
    X_lin = linear_features(res)
    if res.n <= 2 * (X_lin.shape[1] + 9) + 4:
        raise ValueError(f"the residual has {res.n} samples for {X_lin.shape[1] + 9} nuisance coefficients per coordinate; need a longer trajectory")
    # the model's own nonlinear force on the data: its force minus its best linear fit on the nuisance
    beta = np.linalg.lstsq(X_lin, res.f_model, rcond=None)[0]
    g_nl = res.f_model - X_lin @ beta
    in_class_nuisance = ("inertia",)
    out_nuisance = ("potential", "inertia", "input")
    # the null on the sharp residual: what is reported (and what the localisation reads)
    prob_null = Regression(res, folds, res.r, X_lin, out_nuisance)
    probs = {
        False: prob_null if wide is res else Regression(wide, blocked_folds(wide, n_folds, block_s), wide.r, linear_features(wide), out_nuisance),
        True: Regression(res, folds, res.r + g_nl, X_lin, in_class_nuisance),
    }
    prob_model = Regression(res, folds, g_nl, X_lin, in_class_nuisance)  # what the model itself carries of an in-class effect
    return probs, prob_null, prob_model


def _null_of(prob: Regression) -> dict[str, Any]:
    ssr = float(prob.r0 @ prob.r0)
    return {"ssr": ssr, "bic": prob.bic(ssr, prob.pn), "k": prob.pn, "N": prob.N, "excess_over_noise": ssr / prob.N}


def _null_summary(res: Residual, wide: Residual, probs: dict[bool, Regression], pb: Regression) -> tuple[dict[str, Any], dict[str, Any]]:
    """The fitted nuisance (linear corrections of the model) and the null hypothesis's fit statistics."""
    d = res.d
    coef0 = np.linalg.lstsq(pb.Zn, pb.y, rcond=None)[0].reshape(d, pb.p0) / pb.w[:, None]
    nuisance = {"dK": (-coef0[:, :d]).tolist(), "dC": (-coef0[:, d : 2 * d]).tolist(), "f0": coef0[:, 2 * d].tolist(),
                "dB": coef0[:, 2 * d + 1 : pb.p_lin].tolist(), "poly": coef0[:, pb.p_lin :].tolist()}  # fmt: skip
    null = {**_null_of(pb), "N_eff": pb.N / res.spacing, "linearised": _null_of(probs[True]),
            "out_of_class": {**_null_of(probs[False]), "sigma_frames": wide.sigma, "N_eff": probs[False].N / wide.spacing}}  # fmt: skip
    return nuisance, null


def _unexplained(null: dict[str, Any], pb: Regression, any_accepted: bool, unexplained_excess: float) -> None:
    """Record the residual left after the nuisance and the accepted effects, and warn when it stays far above the chart noise."""
    left = float(pb.r0 @ pb.r0) / pb.N  # after the nuisance and the accepted effects (sharp residual)
    null["excess_after_effects"] = left
    null["unexplained"] = bool(left > unexplained_excess)
    if null["unexplained"]:
        null["warning"] = (
            f"after the model-class corrections{' and the effects found' if any_accepted else ''} the residual is still "
            f"{math.sqrt(left):.1f}x the chart noise (rms) and no candidate explains it: the model misfits within its own "
            "class (e.g. a distorted chart: try stage2.mass=learned or a better Stage 1), or the effect is not in the library"
        )
