"""What a refit adds to the identified model: the effect terms at order-one scale, the input delay, the chart it reads.

:func:`refit_spec` reads the accepted effects of a diagnosis
(:class:`~lagsplat.diagnose.diagnosis.Diagnosis`) and builds their
energy-consistent terms (:func:`~lagsplat.diagnose.terms.build_term`), each
wrapped in a :class:`ScaledTerm` so that Stage 2 trains order-one
coefficients; :class:`RefitModel` is the augmented Lagrangian the refit trains
(:func:`lagsplat.diagnose.refit.refit`), and :func:`model_chart` the chart it
reads (input delayed, clip time appended).
"""

from __future__ import annotations

import copy
import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from lagsplat.diagnose.effect_terms import EffectTerm
from lagsplat.diagnose.terms import (
    AugmentedLagrangian,
    build_term,
    delay_actuation,
    with_time_channel,
)

__all__ = ["RefitModel", "FORCE_COEFFICIENTS", "ScaledTerm", "RefitSpec", "refit_spec", "model_chart"]


class RefitModel(AugmentedLagrangian):
    """:class:`~lagsplat.diagnose.terms.AugmentedLagrangian` with what the evaluation reads of a Lagrangian.

    :meth:`modal_analysis` is the *base* Lagrangian's linearisation at its rest
    state (the effect terms are not linearised: a smooth Coulomb switch has no
    useful slope at rest); it is reported for reference only.
    """

    def modal_analysis(self, q: torch.Tensor | None = None) -> dict[str, np.ndarray]:
        """The base model's linear modes (see the class docstring)."""
        return self.base.modal_analysis(q) if q is not None else self.base.modal_analysis()

    @property
    def c0(self) -> float:
        """The base model's dissipation floor."""
        return float(getattr(self.base, "c0", 0.0))


#: Constructor arguments of the terms of :mod:`lagsplat.diagnose.effect_terms` that are generalized-force
#: coefficients (scaled by :class:`ScaledTerm`); the others are positions, speeds, frequencies, times.
FORCE_COEFFICIENTS = ("mu", "c2", "k", "k3", "a", "b", "k_rate", "c_rate", "c_floor", "k_floor")


class ScaledTerm(EffectTerm):
    """``scale x inner``: an effect term whose trainable coefficients are of order one.

    Stage 2 trains with Adam, whose steps are about ``lr`` in parameter units
    whatever the parameter's size; the diagnosed coefficients are in the model's
    generalized-force units (tens to thousands), where ``lr = 1e-3`` could not
    move them. The inner term is built at ``coefficients / scale`` and its force
    and potential are multiplied by the fixed ``scale`` (every term of
    :mod:`lagsplat.diagnose.effect_terms` is linear in its force coefficients, the
    drift's clamps included when they are divided too), so the physics and the
    App. A.2 guarantees are the inner term's.

    Args:
        inner: the term at unit-scale coefficients.
        scale: the factor (> 0), generalized-force units.

    Raises:
        ValueError: if ``scale`` is not positive.
    """

    def __init__(self, inner: EffectTerm, scale: float) -> None:
        super().__init__(inner.e)
        if not (math.isfinite(float(scale)) and scale > 0):
            raise ValueError(f"scale must be a positive number, got {scale!r}")
        self.inner = inner
        self.register_buffer("scale", torch.tensor(float(scale)))
        self.kind = inner.kind
        self.needs_time = inner.needs_time

    def magnitude(self, q, qdot, t):
        """``scale x`` the inner term's magnitude ``[B]``."""
        return self.scale.to(q.dtype) * self.inner.magnitude(q, qdot, t)

    def forward(self, q, qdot, t=None):
        """``scale x`` the inner term's force ``[B,d]``."""
        return self.scale.to(q.dtype) * self.inner(q, qdot, t)

    def potential(self, q):
        """``scale x`` the inner term's potential ``[B]``."""
        return self.scale.to(q.dtype) * self.inner.potential(q)

    def spec(self) -> dict[str, Any]:
        """The inner term's spec with its force coefficients multiplied by ``scale`` (the physical values)."""
        sp = self.inner.spec()
        s = float(self.scale)
        return {k: (float(v) * s if k in FORCE_COEFFICIENTS else v) for k, v in sp.items()}

    def storage(self) -> dict[str, Any]:
        """What :func:`~lagsplat.diagnose.refit_io.load_refit` needs to rebuild it: ``{"inner": inner spec, "scale": scale}``."""
        return {"inner": self.inner.spec(), "scale": float(self.scale)}


@dataclass
class RefitSpec:
    """What the refit adds, read off a diagnosis.

    Attributes:
        effects: names of the effects added.
        terms: the :class:`~lagsplat.diagnose.effect_terms.EffectTerm` modules (at their initial values).
        time_channel: a term reads the clip time (extra actuation channel).
        delay_s: actuation delay the refit model reads its input with (0: none).
        not_refit: ``{effect: remedy}`` of effects that have no Stage-2 term.
        init_coefficients: ``[spec]`` of each term at its start.
    """

    effects: list[str] = field(default_factory=list)
    terms: list[EffectTerm] = field(default_factory=list)
    time_channel: bool = False
    delay_s: float = 0.0
    not_refit: dict[str, str] = field(default_factory=dict)
    init_coefficients: list[dict[str, Any]] = field(default_factory=list)

    @property
    def refittable(self) -> bool:
        """Whether the refit changes the model (a term or a delay)."""
        return bool(self.terms) or self.delay_s > 0

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready record."""
        return {
            "effects": list(self.effects), "time_channel": bool(self.time_channel), "delay_s": float(self.delay_s),
            "not_refit": dict(self.not_refit), "init_terms": list(self.init_coefficients),
        }  # fmt: skip


def refit_spec(diagnosis: Any, model: Any | None = None, init: str = "fitted", scale: float = 1.0) -> RefitSpec:
    """The terms (and input delay) that the diagnosis' accepted effects add to the model.

    Args:
        diagnosis: a :class:`~lagsplat.diagnose.diagnosis.Diagnosis` (``effects``).
        model: the fitted model (dissipation floor of the drift clamp).
        init: ``"fitted"`` (in-class terms start from the part the model lacks) or ``"scratch"``.
        scale: factor on every generalized-force coefficient (the gauge change of
            :attr:`RefitConfig.floor_scale <lagsplat.diagnose.refit.RefitConfig.floor_scale>`).

    Returns:
        The :class:`RefitSpec` (empty when nothing is significant).

    Raises:
        ValueError: on an unknown ``init``.
    """
    if init not in ("fitted", "scratch"):
        raise ValueError(f"refit init must be 'fitted' or 'scratch', got {init!r}")
    spec = RefitSpec()
    for fit in getattr(diagnosis, "effects", []):
        spec.effects.append(fit.effect)
        if fit.effect == "actuation_delay":
            spec.delay_s = float(fit.params["tau_s"])
            continue
        if fit.effect == "missing_dof":
            f = fit.params.get("f_hz")
            spec.not_refit[fit.effect] = (
                "a second degree of freedom" + (f" (hidden mode near {float(f):.3g} Hz)" if f else "")
                + ": no Stage-2 term can add it; rerun Stage 1 with system.d + 1 (then chart, Stage 2)"
            )  # fmt: skip
            continue
        f_use = fit
        if init == "fitted" and "model_carries" in (fit.interpretation or {}):  # fitted against the linearisation
            lack = np.asarray(fit.coef, np.float64) - np.asarray(fit.interpretation["model_carries"], np.float64)
            f_use = dataclasses.replace(fit, coef=lack)
        coef = np.asarray(f_use.coef, np.float64) * scale
        unit = float(np.max(np.abs(coef))) if np.any(coef != 0) else 1.0  # ScaledTerm: order-one trainable coefficients
        interp = dict(f_use.interpretation or {})
        if "k_model" in interp:
            interp["k_model"] = float(interp["k_model"]) * scale / unit
        f_use = dataclasses.replace(f_use, coef=coef / unit, interpretation=interp)
        c0 = float(getattr(model, "c0", 1.0)) if model is not None else 1.0
        inner = build_term(f_use, model, c0=c0 / unit)
        if inner is None:  # pragma: no cover - build_term returns None only for the two handled above
            spec.not_refit[fit.effect] = "no Stage-2 term"
            continue
        term = ScaledTerm(inner, unit)
        spec.terms.append(term)
        spec.time_channel |= bool(term.needs_time)
        spec.init_coefficients.append(term.spec())
    return spec


def model_chart(chart: Any, delay_s: float = 0.0, time_channel: bool = False) -> Any:
    """The chart a refit model reads: the same frames and ``q``, its input delayed and/or the time appended.

    Args:
        chart: the :class:`~lagsplat.chart.Chart`.
        delay_s: input delay (s, >= 0; only with actuation).
        time_channel: append the clip time as the last actuation channel.

    Returns:
        A shallow copy (``chart`` itself when nothing changes).
    """
    out = chart
    if delay_s > 0 and chart.n_u:
        out = copy.copy(chart)
        out.u = delay_actuation(chart.u, chart.t, float(delay_s))
    if time_channel:
        out = with_time_channel(out)
    return out
