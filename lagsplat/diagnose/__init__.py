"""Sim-to-real gap diagnosis: which unmodelled effect makes the identified model depart from the recording.

Pipeline (each step usable alone):

1. :func:`~lagsplat.diagnose.residual.residual_force` /
   :func:`~lagsplat.diagnose.residual.residual_from_chart`: the residual
   generalized force ``r = M (qddot_obs - a_model)`` of a fitted model on the
   encoded trajectory (training frames by default), with its noise level.
2. :func:`~lagsplat.diagnose.select.select_effect`: every candidate of
   :data:`~lagsplat.diagnose.effects.EFFECTS` fitted to ``r`` beyond the
   model-class terms, ranked by BIC, accepted only if significant
   (otherwise ``"none"``), with its physical reading and the signatures.
3. :func:`~lagsplat.diagnose.terms.build_term`: the winning effect as an
   energy-consistent torch term for a Stage-2 refit
   (:class:`~lagsplat.diagnose.terms.AugmentedLagrangian`).

:func:`diagnose_chart` chains 1 and 2 for a trained system.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from lagsplat.lazy import lazy_exports

if TYPE_CHECKING:
    from lagsplat.diagnose.diagnosis import Diagnosis
    from lagsplat.diagnose.residual_data import Residual

#: Where each public name lives; imported on first use (the configuration schema imports the diagnosis settings
#: from their modules, and every stage would otherwise pay for the effects' SciPy). ``signatures`` is not among them:
#: it is also a submodule's name, which the import system binds on the package once the submodule is loaded.
_WHERE = {
    "CandidateFit": "diagnosis", "Diagnosis": "diagnosis", "Effect": "effect_base", "EffectTerm": "effect_terms",
    "term_from_spec": "effect_terms", "EFFECTS": "effects", "effect_names": "effects", "get_effect": "effects",
    "LinearOscillator": "oscillator", "fit_linear_oscillator": "oscillator", "residual_force": "residual",
    "residual_from_chart": "residual", "Residual": "residual_data", "select_effect": "select",
    "AugmentedLagrangian": "terms", "build_term": "terms", "delay_actuation": "terms", "with_time_channel": "terms",
}  # fmt: skip


__getattr__, __dir__ = lazy_exports(__name__, _WHERE)


__all__ = [
    "EFFECTS",
    "Effect",
    "effect_names",
    "get_effect",
    "Residual",
    "residual_force",
    "residual_from_chart",
    "LinearOscillator",
    "fit_linear_oscillator",
    "CandidateFit",
    "Diagnosis",
    "select_effect",
    "diagnose_chart",
    "EffectTerm",
    "AugmentedLagrangian",
    "build_term",
    "term_from_spec",
    "delay_actuation",
    "with_time_channel",
]


def diagnose_chart(model: Any, chart: Any, which: int | None = 0, sigma: float | None = None, **select_kwargs: Any) -> tuple["Diagnosis", "Residual"]:
    """Residual of ``model`` on the chart's ``which`` frames (training by default), then :func:`select_effect`.

    Args:
        model: the fitted model (``acceleration`` / ``mass_matrix`` interface).
        chart: the :class:`~lagsplat.chart.Chart`.
        which: split used (``0`` train, ``1`` held-out, ``None`` all); the
            held-out frames should stay out of the diagnosis so the gap can be
            measured on them afterwards.
        sigma: smoothing, frames (default automatic).
        **select_kwargs: passed to :func:`select_effect`; the model's modal
            frequencies are passed as ``model_freqs_hz`` when it has ``modal_analysis``.

    Returns:
        ``(diagnosis, residual)``.
    """
    from lagsplat.diagnose.residual import residual_from_chart
    from lagsplat.diagnose.select import select_effect

    res = residual_from_chart(model, chart, which, sigma)
    if "model_freqs_hz" not in select_kwargs and hasattr(model, "modal_analysis"):
        try:
            select_kwargs["model_freqs_hz"] = [float(f) for f in model.modal_analysis()["f_hz"]]
        except Exception:
            pass
    return select_effect(res, **select_kwargs), res
