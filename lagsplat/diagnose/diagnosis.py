"""The outcome of the effect selection: one fitted candidate (:class:`CandidateFit`) and the verdict (:class:`Diagnosis`).

:func:`lagsplat.diagnose.select.select_effect` produces them; their
``to_dict`` records are what ``report.json`` stores (:mod:`lagsplat.diagnose.report`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lagsplat.io.common import jsonable

__all__ = ["CandidateFit", "Diagnosis", "failed_rules"]


def failed_rules(physical: bool, practical: bool, evidence: float, r2: float, cv_gain: float, signature_support: float,
                 min_delta_bic: float, min_r2: float, min_cv_gain: float, cv_gain_own: float = math.nan, struck: bool = False) -> list[str]:  # fmt: skip
    """The significance rules a candidate fails, in order (empty: significant).

    ``"physical"`` (sign), ``"practical"`` (its effect's physical check), ``"evidence"`` (``Delta BIC`` plus
    the signatures' support below ``min_delta_bic``), ``"r2"`` (below ``min_r2``) and ``"cv_gain"`` (below
    ``min_cv_gain``, unless the signatures alone reach ``min_delta_bic`` and the candidate's own cross-validation
    does not lose: ``cv_gain_own >= 0``, the gain with the in-class corrections held at their fit on the whole take,
    :meth:`~lagsplat.diagnose.regression.Regression.cv_sse_own`; ``cv_gain`` where that is not computed; undefined
    passes). ``struck``: an end stop whose reversals are read as impacts on its side
    (:func:`~lagsplat.diagnose.impacts.impact_signature`): the ``"r2"`` rule does not apply to it, because a smooth
    penalty explains little of a bounce, while the impacts are their own evidence (the other rules still hold).
    One rule for the selection (:func:`~lagsplat.diagnose.select.decide`) and for the report's reading of a
    ``report.json`` record.
    """
    own = cv_gain_own if math.isfinite(cv_gain_own) else cv_gain
    cv_ok = cv_gain >= min_cv_gain or (signature_support >= min_delta_bic and not own < 0)
    checks = (("physical", physical), ("practical", practical), ("evidence", evidence >= min_delta_bic), ("r2", r2 >= min_r2 or struck), ("cv_gain", cv_ok))
    return [name for name, ok in checks if not ok]


@dataclass
class CandidateFit:
    """One candidate fitted at its best nonlinear parameters.

    Attributes:
        effect: candidate name (``"none"`` for the null fit).
        params: chosen nonlinear parameters.
        direction: ``[d]`` unit latent direction the effect acts along.
        names: coefficient names; ``coef``, ``se``: ``[p]`` values and standard errors
            (generalized-force units of the model).
        ssr: weighted sum of squared residuals (noise units); ``k``: parameter count.
        bic: information criterion; ``delta_bic``: ``BIC_null - bic`` (higher is better).
        r2: share of the null residual explained; ``cv_gain``: blocked-CV gain over the null; ``cv_gain_own``: the
            same with the in-class corrections held at their fit on the whole take (computed where the signatures
            alone reach ``min_delta_bic``, else ``nan``; :func:`failed_rules`).
        signature_support: evidence of the chart-invariant signatures for this effect, on the ``Delta BIC``
            scale (:meth:`~lagsplat.diagnose.effect_base.Effect.signature_support`); ``evidence``:
            ``delta_bic`` plus it (what the ranking and the decision read).
        physical: sign constraints satisfied (and the fit is not degenerate).
        significant: passes the significance rule (see module docstring).
        practical: large enough physically (:meth:`~lagsplat.diagnose.effect_base.Effect.practical`; for out-of-class effects, a rule of the periodic force, the hidden mode and the drift only).
        force: ``[n,d]`` fitted effect force on the residual samples (not serialised).
        design: ``[n d, p]`` the candidate's stacked, noise-weighted regression columns on the residual
            it was fitted to (the wide one for out-of-class candidates; not serialised).
        interpretation: physical reading (:meth:`~lagsplat.diagnose.effect_base.Effect.interpret`).
        against_linearisation: fitted in the regression on the model's linearisation (in-class
            candidates, and an out-of-class one whose fit there was the better), else on the fitted model's residual.
    """

    effect: str
    params: dict[str, Any]
    direction: np.ndarray
    names: list[str]
    coef: np.ndarray
    se: np.ndarray
    ssr: float
    k: int
    bic: float
    delta_bic: float = 0.0
    r2: float = 0.0
    cv_gain: float = 0.0
    cv_gain_own: float = math.nan
    signature_support: float = 0.0
    physical: bool = True
    significant: bool = False
    practical: bool = True
    force: np.ndarray | None = field(default=None, repr=False)
    design: np.ndarray | None = field(default=None, repr=False)
    interpretation: dict[str, Any] = field(default_factory=dict)
    against_linearisation: bool = False

    @property
    def evidence(self) -> float:
        """``delta_bic`` plus the signatures' support (never less than ``delta_bic``)."""
        return float(self.delta_bic + max(self.signature_support, 0.0))

    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable record (without the per-sample force)."""
        return {
            "effect": self.effect,
            "params": jsonable(self.params),
            "direction": [float(v) for v in self.direction],
            "coefficients": {n: {"value": float(c), "se": float(s)} for n, c, s in zip(self.names, self.coef, self.se)},
            "ssr": float(self.ssr),
            "k": int(self.k),
            "bic": float(self.bic),
            "delta_bic": float(self.delta_bic),
            "r2": float(self.r2),
            "cv_gain": float(self.cv_gain),
            "cv_gain_own": jsonable(float(self.cv_gain_own)),
            "signature_support": float(self.signature_support),
            "evidence": self.evidence,
            "physical": bool(self.physical),
            "practical": bool(self.practical),
            "significant": bool(self.significant),
            "interpretation": jsonable(self.interpretation),
        }


@dataclass
class Diagnosis:
    """The verdict of :func:`~lagsplat.diagnose.select.select_effect`.

    Attributes:
        winner: name of the first accepted effect, or ``"none"`` (nothing significant).
        effects: accepted effects in the order found (greedy forward selection).
        ranking: every candidate of the first round, best ``delta_bic`` first.
        null: the nuisance-only fit on the (sharp) residual (``ssr``, ``bic``,
            ``excess_over_noise`` = SSR / N: about 1 when the residual is consistent
            with the chart noise; ``excess_after_effects``, ``unexplained`` and
            ``warning`` for what the accepted effects leave; ``linearised``: the null of
            the in-class regression; ``out_of_class``: the null of the out-of-class
            regression on the wide residual, with its ``sigma_frames``).
        evidence: :func:`~lagsplat.diagnose.signatures.signatures`.
        nuisance: the model-class corrections of the null fit (``dK``, ``dC``, ``f0``).
        settings: thresholds and counts used.
    """

    winner: str
    effects: list[CandidateFit]
    ranking: list[CandidateFit]
    null: dict[str, Any]
    evidence: dict[str, Any]
    nuisance: dict[str, Any]
    settings: dict[str, Any]

    @property
    def labels(self) -> list[str]:
        """Names of the accepted effects (empty when nothing is significant)."""
        return [f.effect for f in self.effects]

    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable record (for ``report.json``)."""
        return {
            "winner": self.winner,
            "effects": [f.to_dict() for f in self.effects],
            "ranking": [f.to_dict() for f in self.ranking],
            "null": jsonable(self.null),
            "evidence": jsonable(self.evidence),
            "nuisance": jsonable(self.nuisance),
            "settings": jsonable(self.settings),
        }

    def summary(self) -> str:
        """A few lines of text: the verdict, the ranking and the evidence."""
        lines = [f"verdict: {self.winner if self.winner != 'none' else 'nothing significant'}"]
        for f in self.effects:
            lines.append(f"  {f.effect}: dBIC = {f.delta_bic:.1f}, R2 = {f.r2:.2f}, CV gain = {f.cv_gain:.2f}; {f.interpretation.get('text', '')}")
        lines.append(f"residual / noise (null) = {self.null['excess_over_noise']:.2f}")
        if self.null.get("warning"):
            lines.append("warning: " + self.null["warning"])
        if self.settings.get("cv_folds", 2) < 2:
            lines.append(f"warning: {self.settings.get('n_samples')} residual samples make a single cross-validation block: no candidate can be significant")
        lines.append("ranking: " + ", ".join(f"{f.effect} ({f.delta_bic:.1f}{'' if f.physical else ', unphysical'})" for f in self.ranking))
        ev = self.evidence
        if "envelope" in ev and ev["envelope"].get("best"):
            lines.append(f"envelope decay: best {ev['envelope']['best']}")
        if "frequency" in ev and "slope_amp2" in ev["frequency"]:
            fr = ev["frequency"]
            lines.append(f"frequency vs amplitude^2: z = {fr['z_amp2']:.1f}; vs time: z = {fr['z_time']:.1f}")
        if ev.get("spectrum", {}).get("unexplained_peaks_hz"):
            lines.append("residual peaks the model lacks (Hz): " + ", ".join(f"{p:.3g}" for p in ev["spectrum"]["unexplained_peaks_hz"]))
        return "\n".join(lines)
