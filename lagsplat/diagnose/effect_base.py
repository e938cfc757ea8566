"""The interface of a candidate unmodelled effect (:class:`Effect`); the library itself is :mod:`lagsplat.diagnose.effects`.

A candidate is a generalized force ``f_eff = e phi(s, sdot, t, u)^T w`` along
one unit latent direction ``e`` that enters the right-hand side of the
Euler-Lagrange equation (paper Eq. 7) additively: features ``phi`` linear in
the coefficients ``w``, a few nonlinear parameters profiled over a grid, and a
physical reading of the fit (see the module docstring of
:mod:`lagsplat.diagnose.effects`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from lagsplat.diagnose.residual_data import Residual, SegmentState

__all__ = ["Effect", "Feature", "ratio"]

#: A candidate's feature function: the de-blurred state of a padded segment -> ``[m, p]`` (or ``[m]``) generalized-force features.
Feature = Callable[[SegmentState], np.ndarray]


def ratio(a: float, b: float) -> float:
    """``a / b`` as a float, NaN when ``b`` is zero or not finite (the relative sizes of :meth:`Effect.interpret`)."""
    return float(a / b) if b not in (0.0,) and math.isfinite(b) else float("nan")


@dataclass(frozen=True)
class Effect:
    """One candidate unmodelled effect: its features, parameter grid and reading.

    Attributes:
        name: identifier (also the synthetic label, :mod:`lagsplat.synth.effects`).
        title: a human-readable name.
        kind: ``"dissipative"``, ``"conservative"``, ``"time"`` (explicit time
            dependence), ``"input"`` (acts on the logged actuation) or ``"mode"``
            (a hidden degree of freedom).
        positive: the coefficients must be ``>= 0`` for the effect to be physical.
        n_nonlinear: number of profiled nonlinear parameters (counted by the information criterion).
        signature: the evidence expected in the data if the effect is present.
        in_class: a conservative, position-only force that the model class itself can
            partly represent (a convex potential can bend to follow it): such a
            candidate is fitted against the model's *linearisation* (so that what the
            model has absorbed, or mis-learned, is seen in full) and must pass a
            minimum physical size (:meth:`practical`).
        also_in_class: an out-of-class effect with a conservative part that a potential can
            partly absorb on a decaying oscillation (a drifting stiffness: early, large swings
            stiffer than late, small ones looks like a hardening spring): fitted in both
            regressions where :meth:`against_linearisation_allowed`, the one giving the larger
            ``Delta BIC`` kept.
    """

    name: str
    title: str
    kind: str
    positive: bool
    n_nonlinear: int
    signature: str
    in_class: bool = False
    also_in_class: bool = False

    #: the effect is a slow change of the system's parameters in time, which on one steady decay the amplitude
    #: stands in for (:func:`~lagsplat.diagnose.select.state_laws_first`)
    trend_in_time: ClassVar[bool] = False

    # ------------------------------------------------------------------ interface
    def applicable(self, res: Residual) -> bool:
        """Whether the effect can be tested on this residual (e.g. a delay needs actuation)."""
        return True

    def grid(self, res: Residual, e: np.ndarray, r0: np.ndarray) -> list[dict[str, Any]]:
        """Values of the nonlinear parameters to profile over.

        Args:
            res: the residual.
            e: ``[d]`` unit direction of the effect.
            r0: ``[n]`` the residual along ``e`` after the nuisance (model-class) terms are removed.
        """
        return [{}]

    def refine(self, res: Residual, e: np.ndarray, best: dict[str, Any]) -> list[dict[str, Any]]:
        """A finer grid around the best coarse value (empty: no refinement)."""
        return []

    def feature(self, res: Residual, e: np.ndarray, params: dict[str, Any]) -> tuple[Feature, list[str]]:
        """``(phi, names)``: the feature function on a :class:`SegmentState` (``-> [m,p]``) and its column names."""
        raise NotImplementedError

    def interpret(self, coef: np.ndarray, se: np.ndarray, params: dict[str, Any], res: Residual, e: np.ndarray, scale: dict[str, float]) -> dict[str, Any]:
        """Physical reading of the fitted coefficients (values, standard errors, relative sizes).

        Args:
            coef, se: ``[p]`` coefficients and their standard errors (generalized-force units).
            params: the chosen nonlinear parameters.
            res: the residual.
            e: ``[d]`` direction.
            scale: ``{"k": linear stiffness along e, "c": linear damping along e,
                "s_rms", "s_raw_rms" (the chart's unsmoothed positions), "sdot_rms", "s_bar",
                "t_bar"}`` of the fitted model and data.
        """
        return {}

    def practical(self, interpretation: dict[str, Any], thresholds: dict[str, float]) -> tuple[bool, str]:
        """Whether the fitted effect is large enough to matter physically, and why not.

        In-class candidates have a size rule (:class:`~lagsplat.diagnose.effects_state.CubicStiffnessEffect`,
        :class:`~lagsplat.diagnose.effects_state.EndStopEffect`), and so do the periodic force and the hidden
        mode (:class:`~lagsplat.diagnose.effects_time.PeriodicForceEffect`,
        :class:`~lagsplat.diagnose.effects_time.MissingDofEffect`: the motion they drive must reach 1 % of the
        recorded one); a drift's stiffness change must not be contradicted by the recorded periods
        (:class:`~lagsplat.diagnose.effects_time.DriftEffect`); the others must merely pass the statistical rule.
        """
        return True, ""

    def against_linearisation_allowed(self, evidence: dict[str, Any], thresholds: dict[str, float]) -> bool:
        """Whether an :attr:`also_in_class` effect may also be fitted against the model's linearisation on this
        recording (``evidence``: :func:`~lagsplat.diagnose.signatures.signatures`). Default: always."""
        return True

    def fitted_support(self, fit: Any, res: Any, thresholds: dict[str, float]) -> tuple[float, str]:
        """Evidence for this effect *as fitted* (its parameters, side, frequency), beside the regression: ``(support, reading)``.

        On the ``Delta BIC`` scale, added to the fit's :attr:`~lagsplat.diagnose.diagnosis.CandidateFit.signature_support`
        once its ``delta_bic`` is known. A hidden mode reads the image
        (:meth:`~lagsplat.diagnose.effects_time.MissingDofEffect.fitted_support`), an end stop how sharply the motion
        turns around on its side (:meth:`~lagsplat.diagnose.effects_state.EndStopEffect.fitted_support`); default ``(0, "")``.

        Args:
            fit: the :class:`~lagsplat.diagnose.diagnosis.CandidateFit`, ``delta_bic`` set.
            res: the :class:`~lagsplat.diagnose.residual_data.Residual` it was fitted on (``meta["signatures"]`` set).
            thresholds: the selection's thresholds (``min_delta_bic`` and the effects' own).
        """
        return 0.0, ""

    def signature_support(self, evidence: dict[str, Any]) -> tuple[float, str]:
        """Evidence for this effect in the chart-invariant signatures, beside the regression: ``(support, reading)``.

        ``support`` is on the scale of ``Delta BIC`` (:func:`~lagsplat.diagnose.signatures.signatures`:
        the envelope's ``support`` and the rest's), and :func:`~lagsplat.diagnose.select.decide` adds it
        to the candidate's own. Most effects leave no signature of that kind: ``(0, "")``.

        Args:
            evidence: :func:`~lagsplat.diagnose.signatures.signatures` of the residual.
        """
        return 0.0, ""

    # ------------------------------------------------------------------ helpers
    @staticmethod
    def coords(st: SegmentState, e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(s, sdot)`` ``[m]`` of a segment along ``e``."""
        return st.q @ e, st.qdot @ e
