"""Fitting the candidate effects: each profiled over its grid and directions, with standard errors and a physical reading.

The *fit* step of :func:`lagsplat.diagnose.select.select_effect` (see
"Ranking and significance" in :mod:`lagsplat.diagnose.select`): every
remaining candidate of :mod:`lagsplat.diagnose.effects` is fitted in its
:class:`~lagsplat.diagnose.regression.Regression` (linear least squares in its
coefficients, non-negative where physics fixes the sign, profiled over its
nonlinear parameters and the latent directions), and scored by ``Delta BIC``
and ``R2`` against the nuisance-only fit.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from lagsplat.diagnose.diagnosis import CandidateFit
from lagsplat.diagnose.effect_base import Effect
from lagsplat.diagnose.effects import get_effect
from lagsplat.diagnose.regression import Regression
from lagsplat.diagnose.residual_data import Residual

__all__ = ["model_scales", "candidate_design", "fit_candidate", "fit_candidates"]


def model_scales(res: Residual, e: np.ndarray) -> dict[str, float]:
    """Linear stiffness / damping of the model along ``e`` (regression of its force on q, qdot) and data scales.

    Returns:
        ``{"k", "c", "s_rms", "s_raw_rms", "sdot_rms", "s_bar", "t_bar"}``: the ``scale`` argument of
        :meth:`~lagsplat.diagnose.effect_base.Effect.interpret` (generalized-force units per
        latent unit, per latent unit per second; latent units; seconds).
    """
    s, v = res.q @ e, res.qdot @ e
    X = np.stack([s - s.mean(), v, np.ones_like(s)], 1)
    f = res.f_model @ e
    coef = np.linalg.lstsq(X, f, rcond=None)[0]
    return {
        "k": float(-coef[0]), "c": float(-coef[1]), "s_rms": float(np.std(s)), "s_raw_rms": float(np.std(res.q_raw @ e)),
        "sdot_rms": float(np.sqrt(np.mean(v**2))),
        "s_bar": float(s.mean()), "t_bar": float(np.mean(res.t)),
    }  # fmt: skip


def candidate_design(prob: Regression, fit: CandidateFit) -> np.ndarray:
    """A fitted candidate's stacked columns ``[N,p]`` on ``prob``'s own residual (its features at the fit's parameters and direction)."""
    eff = get_effect(fit.effect)
    phi, _ = eff.feature(prob.res, fit.direction, fit.params)
    return prob.stack(prob.res.features(phi), fit.direction)


def _profile(prob: Regression, eff: Effect, dirs: Sequence[np.ndarray]) -> tuple[float, Any] | None:
    """The least-SSR fit over the coarse grid of every direction, then the refinement around it: ``(ssr, (e, params, names, X, Zc, w, Zt))``."""
    res = prob.res
    best: tuple[float, Any] | None = None

    def scan(e: np.ndarray, grid: list[dict[str, Any]]) -> None:
        nonlocal best
        for params in grid:
            phi, names = eff.feature(res, e, params)
            X = res.features(phi)
            Zc = prob.stack(X, e)
            w, ssr, Zt = prob.fit(Zc, eff.positive)
            if best is None or ssr < best[0]:
                best = (ssr, (e, params, names, X, Zc, w, Zt))

    for e in dirs:
        r0e = (prob.r0.reshape(res.d, res.n) / prob.w[:, None]).T @ e  # nuisance-free residual along e (force units)
        scan(e, eff.grid(res, e, r0e))
    if best is None:
        return None
    e_best, p_best = best[1][0], best[1][1]
    scan(e_best, eff.refine(res, e_best, p_best))
    return best


def fit_candidate(prob: Regression, eff: Effect, dirs: Sequence[np.ndarray], extra_k: int, thresholds: dict[str, float]) -> CandidateFit | None:
    """Profile one candidate over its grid and directions; the best fit with standard errors and its reading.

    Args:
        prob: the regression the candidate is fitted in.
        eff: the candidate.
        dirs: unit ``[d]`` latent directions to try (:func:`~lagsplat.diagnose.signatures.directions`).
        extra_k: parameters counted for the direction (``d - 1``).
        thresholds: the physical-size rules of :meth:`~lagsplat.diagnose.effect_base.Effect.practical`.

    Returns:
        The :class:`~lagsplat.diagnose.diagnosis.CandidateFit` (``delta_bic``, ``r2``, ``cv_gain``
        not yet set), or ``None`` when the candidate's grid is empty.
    """
    res = prob.res
    best = _profile(prob, eff, dirs)
    if best is None:
        return None
    ssr, (e, params, names, X, Zc, w, Zt) = best
    p = len(w)
    k = prob.pn + p + eff.n_nonlinear + extra_k
    dof = max(prob.N - prob.pn - p, 1)
    s2 = ssr / dof
    try:
        cov = s2 * res.spacing * np.linalg.pinv(Zt.T @ Zt)
        se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    except np.linalg.LinAlgError:
        se = np.full(p, np.nan)
    physical = bool(np.any(w != 0)) and (not eff.positive or bool(np.all(w >= 0)))
    fit = CandidateFit(eff.name, params, e, names, w, se, ssr, k, prob.bic(ssr, k), physical=physical)
    fit.force = (X @ w)[:, None] * e[None, :]
    fit.design = Zc
    fit.interpretation = eff.interpret(w, se, params, res, e, model_scales(res, e))
    ok, why = eff.practical(fit.interpretation, thresholds)
    fit.practical = ok
    if not ok:
        fit.interpretation["below_practical_size"] = why
    fit.signature_support, reading = eff.signature_support(res.meta.get("signatures") or {})
    if reading:
        fit.interpretation["signature"] = reading
    return fit


def fit_candidates(
    remaining: Sequence[Effect], probs: dict[bool, Regression], prob_model: Regression, dirs: dict[bool, list[np.ndarray]], extra_k: int,
    thresholds: dict[str, float],
) -> list[CandidateFit]:
    """Fit each remaining effect in its regression and score it against the nuisance-only fit (the *fit* step).

    Args:
        remaining: the candidates still in the search.
        probs: ``{in_class: regression}`` (in-class candidates on the model's linearisation; an effect
            with :attr:`~lagsplat.diagnose.effect_base.Effect.also_in_class` in both where its signature allows,
            :meth:`~lagsplat.diagnose.effect_base.Effect.against_linearisation_allowed`; the larger ``Delta BIC`` kept).
        prob_model: the regression of the model's own nonlinear force: how much of an in-class
            effect the model already carries (``interpretation["model_carries"]``, ``"model_share"``).
        dirs: ``{in_class: directions}``.
        extra_k, thresholds: see :func:`fit_candidate`.

    Returns:
        The fits, in the order of ``remaining``, with ``delta_bic`` and ``r2`` set, and the support for each as
        fitted (:meth:`~lagsplat.diagnose.effect_base.Effect.fitted_support`) added to ``signature_support``.
    """
    ref = {k: (float(p.r0 @ p.r0), p.bic(float(p.r0 @ p.r0), p.pn)) for k, p in probs.items()}
    fits = []
    for eff in remaining:
        fit = None
        sig = probs[True].res.meta.get("signatures") or {}
        both = eff.also_in_class and eff.against_linearisation_allowed(sig, thresholds)
        for lin in dict.fromkeys((eff.in_class, eff.in_class or both)):  # one or both regressions
            f = fit_candidate(probs[lin], eff, dirs[lin], extra_k, thresholds)
            if f is None:
                continue
            f.delta_bic = ref[lin][1] - f.bic
            f.r2 = 1.0 - f.ssr / max(ref[lin][0], 1e-300)
            f.against_linearisation = lin
            f.interpretation["fitted_against"] = "model linearisation" if lin else "fitted model"
            if fit is None or f.delta_bic > fit.delta_bic:
                fit = f
        if fit is None:
            continue
        extra, reading = eff.fitted_support(fit, probs[fit.against_linearisation].res, thresholds)
        if reading:
            fit.signature_support += extra
            fit.interpretation["signature"] = "; ".join(filter(None, (fit.interpretation.get("signature"), reading)))
            fit.interpretation["text"] = f"{fit.interpretation.get('text', '')}; {reading}"
        if fit.against_linearisation:
            w_model, _, _ = prob_model.fit(fit.design, False)
            fit.interpretation["model_carries"] = [float(v) for v in w_model]
            fit.interpretation["model_share"] = [float(m / c) if c != 0 else float("nan") for m, c in zip(w_model, fit.coef)]
        fits.append(fit)
    return fits
