"""How far the gap shrinks: refit Stage 2 with the diagnosed effect and measure the held-out gap.

Refit
-----
The winning effect(s) of :func:`lagsplat.diagnose.select_effect` become
energy-consistent torch terms (:func:`lagsplat.diagnose.terms.build_term`)
added to the Lagrangian (:class:`RefitModel`, an
:class:`~lagsplat.diagnose.terms.AugmentedLagrangian`), and Stage 2 is run
again by :func:`lagsplat.train.stage2.train_stage2` itself (same windows, loss,
optimiser and model selection on *training* rollouts, paper §3.3, Eq. 8),
through its ``augment`` hook:

* ``init="fitted"`` (default): the Lagrangian starts from the fitted weights
  and is fine-tuned together with the term for ``epochs`` epochs. In-class
  effects (cubic stiffness, end stop) start from the part the fitted model
  lacks (``coef - interpretation["model_carries"]``); the others from the
  diagnosed coefficients;
* ``init="scratch"``: a fresh Stage 2 (the configured epochs), the term
  initialised at the diagnosed coefficients.

An **actuation delay** is not a force: the refit model reads the logged input
``tau`` seconds late (:func:`~lagsplat.diagnose.terms.delay_actuation`, the
diagnosed ``tau``). Time-dependent terms (periodic force, drift) read the clip
time from an extra actuation channel
(:func:`~lagsplat.diagnose.terms.with_time_channel`). A **missing degree of
freedom** has no term: the remedy is Stage 1 with one more latent dimension,
which this module does not run (:attr:`RefitSpec.not_refit`).

``control=True`` also runs the identical fine-tune *without* the term, so that
what the term buys is separated from what more training buys.

Energy bound
------------
The dissipative terms satisfy ``qdot^T f_eff <= 0`` by construction
(:mod:`lagsplat.diagnose.terms`), so the bound of paper App. A.2
(``dE/dt <= -c0 |qdot|^2`` on a free rollout) holds for the refit model;
:func:`~lagsplat.diagnose.gap.energy_check` verifies it numerically (the power of the dissipative
terms on the training states, and the energy ``T + V + V_eff`` along free
rollouts of a model without time-dependent terms or inputs).

Held-out gap
------------
:func:`~lagsplat.diagnose.gap.held_out_gap` scores a model on the held-out frames, which neither the
diagnosis (training frames) nor the refit (training frames, selection on
training rollouts) saw, with the code of :func:`lagsplat.evaluate.evaluate`
(``eps_q``, ``eps_freq``, ``eps_I``, ``eps_AE``), plus the envelope decay of
:func:`~lagsplat.diagnose.gap.envelope_decay`: a free rollout from the start of the longest held-out
segment over its whole length, started past the smoothing's edge
(:func:`lagsplat.timeseries.smoothing_edge`: read at a mid-swing first frame the
velocity is about halved, and a friction model started with too little energy
stops early); the amplitude of each half cycle (half the
difference of consecutive extrema of the most visible coordinate, offset-free)
is fitted by a linear and an exponential envelope, the form that fits the
encoded trajectory best is used for both, and the decay is the fraction of
amplitude lost over the segment, ``D = 1 - A(t_end) / A(t_0)``; the error is
``|D_sim - D_enc| / max(|D_enc|, 0.05)``. The image gap is the excess over
the AE floor, ``(eps_I - eps_AE) / eps_AE``.

Chart-noise floor
-----------------
The encoded trajectory is a measurement: part of ``eps_q`` and ``eps_freq`` is
its noise, which no model removes (the latent counterpart of the AE floor that
the image error is taken over, paper §4.1). :func:`~lagsplat.diagnose.gap.noise_floor` measures it by
Monte Carlo: the model's own free motion over the held-out segment (from the
recording's state past the smoothing edge, with the recording's actuation),
plus white noise at the chart's level (:func:`lagsplat.diagnose.residual.chart_noise`,
fourth differences of the held-out encodings), scored by the same
:func:`lagsplat.evaluate.evaluate` protocol. That is what a model with no gap
at all would score on a chart this noisy. ``eps_q_over_floor = eps_q -
eps_q_floor`` (likewise ``eps_freq``) is the part of the gap the chart's noise
does not explain; where it is not positive, nothing above the noise is left to
shrink and its reduction is undefined. The floor depends on the model (a model
with a stop turns the same noise into larger errors than a linear one), so
gaps that are compared are taken over one floor, the lowest of theirs
(:func:`~lagsplat.diagnose.gap.common_noise_floor`), as the benchmark's images are over the lower
AE floor.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from lagsplat.diagnose.effects import get_effect
from lagsplat.diagnose.terms import (
    AugmentedLagrangian,
    EffectTerm,
    build_term,
    delay_actuation,
    term_from_spec,
    with_time_channel,
)
from lagsplat.io.atomic import save_torch

__all__ = [
    "RefitConfig",
    "RefitSpec",
    "RefitModel",
    "ScaledTerm",
    "RefitResult",
    "refit_spec",
    "model_chart",
    "refit",
    "choose_by_refit",
    "add_control",
    "save_refit",
    "load_refit",
    "GAP_METRICS",
]

#: The gap numbers compared before / after (name -> lower is better).
GAP_METRICS = ("eps_q", "eps_freq", "envelope_decay_error", "image_excess", "eps_q_over_floor", "eps_freq_over_floor")


@dataclass
class RefitConfig:
    """Refit settings (``conf/config.yaml``, group ``diagnose.refit``).

    Attributes:
        enabled: refit when an effect is found.
        init: ``"fitted"`` (fine-tune the fitted Lagrangian with the term) or ``"scratch"``.
        epochs: Stage-2 epochs of the fine-tune (``init="fitted"``); ``None`` keeps
            the Stage-2 setting (always the case for ``"scratch"``).
        lr: learning rate of the fine-tune (``None``: the Stage-2 one).
        control: also fine-tune without the term (same settings and seed).
        seed: RNG seed of the refit.
        floor_scale: energy-gauge factor ``g`` applied to the fitted model before the
            fine-tune (``s_M, s_V += log g``, term coefficients ``x g``), so that the fixed
            dissipation floor ``c0`` weighs ``g`` times less (paper App. C fixes it at a
            damping ratio ``stage2.zeta_floor`` of the training frequency, which can exceed
            the true damping once a dry friction or drag carries the decay). The damping
            the floor gives up moves into the learned dissipation (:func:`_gauged`), so the
            fine-tune starts from the fitted dynamics. ``1``: no change. Applied to the
            control too.
        choose: when several candidates with a Stage-2 remedy pass the significance
            rule, confirm the Delta-BIC winner by its refit's *training*-rollout error
            and fall back to the best rival whose refit beats the identified model
            (:func:`choose_by_refit`, the model selection of paper §3.3);
            ``False``: the Delta-BIC order decides alone.
    """

    enabled: bool = True
    init: str = "fitted"
    epochs: int | None = 100
    lr: float | None = None
    control: bool = True
    seed: int = 0
    floor_scale: float = 4.0
    choose: bool = True

    @classmethod
    def from_mapping(cls, m: Mapping[str, Any] | None) -> RefitConfig:
        """Build from a (Hydra) mapping; unknown keys raise ``KeyError``."""
        from lagsplat.train.config import dataclass_from_mapping

        return dataclass_from_mapping(cls, dict(m or {}), "diagnose.refit")


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


#: Constructor arguments of the terms of :mod:`lagsplat.diagnose.terms` that are generalized-force
#: coefficients (scaled by :class:`ScaledTerm`); the others are positions, speeds, frequencies, times.
FORCE_COEFFICIENTS = ("mu", "c2", "k", "k3", "a", "b", "k_rate", "c_rate", "c_floor", "k_floor")


class ScaledTerm(EffectTerm):
    """``scale x inner``: an effect term whose trainable coefficients are of order one.

    Stage 2 trains with Adam, whose steps are about ``lr`` in parameter units
    whatever the parameter's size; the diagnosed coefficients are in the model's
    generalized-force units (tens to thousands), where ``lr = 1e-3`` could not
    move them. The inner term is built at ``coefficients / scale`` and its force
    and potential are multiplied by the fixed ``scale`` (every term of
    :mod:`lagsplat.diagnose.terms` is linear in its force coefficients, the
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
        return self.scale.to(q.dtype) * self.inner.magnitude(q, qdot, t)

    def forward(self, q, qdot, t=None):
        return self.scale.to(q.dtype) * self.inner(q, qdot, t)

    def potential(self, q):
        return self.scale.to(q.dtype) * self.inner.potential(q)

    def spec(self) -> dict[str, Any]:
        """The inner term's spec with its force coefficients multiplied by ``scale`` (the physical values)."""
        sp = self.inner.spec()
        s = float(self.scale)
        return {k: (float(v) * s if k in FORCE_COEFFICIENTS else v) for k, v in sp.items()}

    def storage(self) -> dict[str, Any]:
        """What :func:`load_refit` needs to rebuild it: ``{"inner": inner spec, "scale": scale}``."""
        return {"inner": self.inner.spec(), "scale": float(self.scale)}


@dataclass
class RefitSpec:
    """What the refit adds, read off a diagnosis.

    Attributes:
        effects: names of the effects added.
        terms: the :class:`~lagsplat.diagnose.terms.EffectTerm` modules (at their initial values).
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
        diagnosis: a :class:`~lagsplat.diagnose.select.Diagnosis` (``effects``).
        model: the fitted model (dissipation floor of the drift clamp).
        init: ``"fitted"`` (in-class terms start from the part the model lacks) or ``"scratch"``.
        scale: factor on every generalized-force coefficient (the gauge change of
            :attr:`RefitConfig.floor_scale`).

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
        if init == "fitted" and get_effect(fit.effect).in_class and "model_carries" in (fit.interpretation or {}):
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


@dataclass
class RefitResult:
    """A refit model with the chart it reads.

    Attributes:
        model: the refit model (:class:`RefitModel`, or the plain Lagrangian for a pure delay).
        chart: the chart it is evaluated on (:func:`model_chart`).
        spec: what was added; history: the Stage-2 history of the refit.
        control: the fine-tune without the term (``None`` if not run); control_history its history.
        fitted_terms: ``[spec]`` of each term after the refit (the identified coefficients).
    """

    model: nn.Module
    chart: Any
    spec: RefitSpec
    history: dict
    control: nn.Module | None = None
    control_history: dict | None = None
    fitted_terms: list[dict[str, Any]] = field(default_factory=list)


def _stage2_settings(stage2_cfg: Any, cfg: RefitConfig) -> Any:
    s2 = copy.deepcopy(stage2_cfg)
    if cfg.init == "fitted":
        if cfg.epochs is not None:
            s2.epochs = int(cfg.epochs)
        if cfg.lr is not None:
            s2.lr = float(cfg.lr)
    return s2


def refit(
    chart: Any, model: nn.Module, stage2_cfg: Any, diagnosis: Any, cfg: RefitConfig | None = None, inertia: Any | None = None,
    progress: bool = False,
) -> RefitResult | None:
    """Refit Stage 2 with the diagnosed effect(s) added (module docstring).

    Args:
        chart: the chart the model was fitted on (only its training frames are used).
        model: the fitted Lagrangian (its weights are the fine-tune's start; not modified).
        stage2_cfg: the :class:`~lagsplat.train.stage2.Stage2Config` it was fitted with.
        diagnosis: the :class:`~lagsplat.diagnose.select.Diagnosis`.
        cfg: refit settings.
        inertia: the decoder inertia for ``mass="decoder"``.
        progress: tqdm bar.

    Returns:
        The :class:`RefitResult`, or ``None`` when nothing is significant or no
        accepted effect has a Stage-2 remedy (missing degree of freedom only).

    Raises:
        ValueError: on an unknown ``cfg.init`` or a non-positive ``cfg.floor_scale``.
    """
    from lagsplat.train.stage2 import train_stage2

    cfg = cfg or RefitConfig()
    gauge = _gauge(cfg)
    if not gauge > 0:
        raise ValueError(f"refit floor_scale must be positive, got {cfg.floor_scale!r}")
    spec = refit_spec(diagnosis, model, cfg.init, gauge)
    if not spec.refittable:
        return None
    s2 = _stage2_settings(stage2_cfg, cfg)
    ch = model_chart(chart, spec.delay_s, spec.time_channel)
    augment = _augmenter(model, cfg, gauge, spec.terms, spec.time_channel)
    new, hist = train_stage2(ch, s2, seed=cfg.seed, progress=progress, inertia=inertia, augment=augment, n_u_model=chart.n_u)
    out = RefitResult(new, ch, spec, hist)
    if isinstance(new, AugmentedLagrangian):
        out.fitted_terms = [t.spec() for t in new.terms]
    if cfg.control:
        add_control(out, chart, model, stage2_cfg, cfg, inertia, progress)
    return out


def _gauge(cfg: RefitConfig) -> float:
    """The energy-gauge factor a refit applies (:attr:`RefitConfig.floor_scale`; 1 for a scratch refit)."""
    return float(cfg.floor_scale) if cfg.init == "fitted" else 1.0


@torch.no_grad()
def _gauged(base: nn.Module, gauge: float) -> None:
    """Apply the energy gauge ``g`` to a fitted Lagrangian in place, keeping its dynamics at the chart origin.

    ``s_M, s_V += log g`` scales ``M`` and ``V`` by ``g``; the dynamics is unchanged if
    ``C = e^{s_M} L_C L_C^T + c0 I`` is scaled by ``g`` too, but the floor ``c0`` is fixed,
    so the learned part takes over what the floor gives up:
    ``L_C L_C^T <- L_C L_C^T(0) + (g - 1) c0 / e^{s_M'} I``, made constant (the last layer
    of :class:`~lagsplat.models.lagrangian.CholeskyField` set to that Cholesky factor,
    weights zero). Exact where the fitted field is constant; in practice it has
    collapsed (``L_C L_C^T`` ~ 1e-29 on the blind suite's end-stop clips, as the floor
    already over-damps), and there its gradient vanishes (softplus far below zero),
    so without this the fine-tune starts ``g`` times less damped and cannot raise the
    damping again: those refits ran 5-8 % fast with swings too large.
    """
    base.s_M.add_(math.log(gauge))
    base.s_V.add_(math.log(gauge))
    field = base.dissipation
    extra = (gauge - 1.0) * base.c0 / float(torch.exp(base.s_M))
    target = field(torch.zeros(1, base.d))[0].double() + extra * torch.eye(base.d, dtype=torch.float64)
    L = torch.linalg.cholesky(target)
    raw = L[field.ii, field.jj]
    diag = field.ii == field.jj
    raw[diag] = raw[diag] + torch.log(-torch.expm1(-raw[diag]))  # inverse softplus
    last = field.net[-1]
    last.weight.zero_()
    last.bias.copy_(raw.to(last.bias.dtype))


def _augmenter(model: nn.Module, cfg: RefitConfig, gauge: float, terms: Sequence[EffectTerm], time_channel: bool):
    """The ``augment`` hook of :func:`~lagsplat.train.stage2.train_stage2` for a refit (fitted start, gauge, terms)."""
    fitted_state = copy.deepcopy(model.state_dict())

    def augment(base: nn.Module) -> nn.Module:
        if cfg.init == "fitted":
            base.load_state_dict(fitted_state)
            if gauge != 1.0:
                _gauged(base, gauge)
        if not terms and not time_channel:
            return base
        return RefitModel(base, [copy.deepcopy(t) for t in terms], time_channel=time_channel)

    return augment


def add_control(
    result: RefitResult, chart: Any, model: nn.Module, stage2_cfg: Any, cfg: RefitConfig, inertia: Any | None = None, progress: bool = False
) -> RefitResult:
    """Run the control of a refit (the identical fine-tune without the term) into ``result.control``.

    Args:
        result: the refit (from :func:`refit` or :func:`choose_by_refit`); modified in place.
        chart, model, stage2_cfg, inertia, progress: as for :func:`refit`.
        cfg: the refit settings the result was made with (same seed, epochs, gauge).

    Returns:
        ``result``, with ``control`` and ``control_history`` set.
    """
    from lagsplat.train.stage2 import train_stage2

    s2 = _stage2_settings(stage2_cfg, cfg)
    result.control, result.control_history = train_stage2(
        chart, s2, seed=cfg.seed, progress=progress, inertia=inertia, augment=_augmenter(model, cfg, _gauge(cfg), [], False), n_u_model=chart.n_u
    )
    return result


def choose_by_refit(
    chart: Any, model: nn.Module, stage2_cfg: Any, diagnosis: Any, baseline_nrmse: float | None, cfg: RefitConfig | None = None,
    inertia: Any | None = None,
) -> tuple[Any, list[dict[str, Any]], RefitResult | None]:
    """Confirm the Delta-BIC winner by refitting it; if the refit does not help, the best significant rival that does.

    Several effects can explain one residual about equally (an end stop and a
    stiffening drift both raise the frequency of a bouncing motion as it decays).
    The residual regression ranks them by Delta BIC on the residual alone. Adding
    the winner to the model and fitting again (:func:`refit`, without the control)
    asks whether it makes the *model* follow the training video better: the
    paper's model selection criterion (§3.3: multi-step rollout NRMSE on training
    frames, ``history["selected_nrmse"]`` of :func:`lagsplat.train.stage2.train_stage2`),
    against the identified model's own ``baseline_nrmse``. When it does, the winner
    stands (one extra refit). When it does not, each other significant candidate
    is refit and the one with the lowest training-rollout NRMSE *below the
    baseline* is taken; if none gets below it, the Delta-BIC winner stands. The
    rollout error rewards any added flexibility, not the right physics (on a
    dry-friction clip a cubic-stiffness refit can follow the training video
    better than the friction's, by correcting the model's frequency), so it never
    ranks candidates whose refits help: it only rejects a winner whose refit
    makes the model follow its own training video worse. Held-out frames are not read. Applies when
    there is one accepted effect (``max_effects = 1``, the default) and at least two
    significant candidates with a Stage-2 refit (a missing degree of freedom has
    none and is never compared).

    Args:
        chart, model, stage2_cfg, inertia: as for :func:`refit`.
        diagnosis: the :class:`~lagsplat.diagnose.select.Diagnosis`.
        baseline_nrmse: the identified model's training-rollout NRMSE (Stage-2
            ``selected_nrmse``); ``None``: nothing is compared.
        cfg: refit settings (its ``control`` is ignored here).

    Returns:
        ``(diagnosis, candidates, result)``: the diagnosis with the chosen effect as
        its winner (the input itself when the winner stands or nothing is compared),
        one record per candidate refit (``effect``, ``delta_bic``, ``train_rollout_nrmse``,
        ``beats_identified``: below ``baseline_nrmse``, ``chosen``), empty when nothing was compared, and the
        chosen effect's refit without its control (:func:`add_control` adds it;
        ``None`` when nothing was compared).
    """
    cfg = cfg or RefitConfig()
    effects = list(getattr(diagnosis, "effects", []))
    refittable = [f for f in diagnosis.ranking if f.significant and f.effect != "missing_dof"]
    if baseline_nrmse is None or len(effects) != 1 or effects[0].effect == "missing_dof" or len(refittable) < 2:
        return diagnosis, [], None
    quiet = dataclasses.replace(cfg, control=False)
    first = effects[0]
    order = [first, *[f for f in refittable if f.effect != first.effect]]
    rows: list[dict[str, Any]] = []
    fits: list[RefitResult | None] = []
    for fit in order:
        r = refit(chart, model, stage2_cfg, dataclasses.replace(diagnosis, winner=fit.effect, effects=[fit]), quiet, inertia)
        err = float(r.history.get("selected_nrmse", math.inf)) if r is not None else math.inf
        beats = err < baseline_nrmse
        rows.append({"effect": fit.effect, "delta_bic": float(fit.delta_bic), "train_rollout_nrmse": err, "beats_identified": beats, "chosen": False})
        fits.append(r)
        if fit is first and beats:
            break  # the winner is confirmed: no rival is refit
    better = [k for k, r in enumerate(rows) if r["beats_identified"]]
    k = min(better, key=lambda k: rows[k]["train_rollout_nrmse"]) if better else 0
    rows[k]["chosen"] = True
    chosen = diagnosis if k == 0 else dataclasses.replace(diagnosis, winner=order[k].effect, effects=[order[k]])
    return chosen, rows, fits[k]


# ---------------------------------------------------------------------- persistence
def save_refit(path: str | Path, result: RefitResult, stage2_cfg: Any) -> Path:
    """Write the refit model atomically: base weights, term specs and state, delay, settings."""
    m = result.model
    base = m.base if isinstance(m, AugmentedLagrangian) else m
    return save_torch(path, {
        "base_state_dict": base.state_dict(), "terms": [t.storage() for t in getattr(m, "terms", [])],
        "state_dict": m.state_dict(), "time_channel": bool(getattr(m, "time_channel", False)),
        "delay_s": float(result.spec.delay_s), "config": dataclasses.asdict(stage2_cfg), "d": int(base.d),
        "n_u": int(getattr(base, "n_u", 0)), "effects": list(result.spec.effects), "history": result.history,
    })  # fmt: skip


def load_refit(path: str | Path, inertia: Any | None = None) -> tuple[nn.Module, dict]:
    """Rebuild a model saved by :func:`save_refit` (eval mode); ``(model, checkpoint)``.

    The model reads the chart ``model_chart(chart, ck["delay_s"], ck["time_channel"])``
    (:func:`model_chart`: the input delayed and / or the clip time appended).

    Raises:
        FileNotFoundError: if ``path`` does not exist.
        KeyError: if a term class is unknown.
    """
    from lagsplat.train.stage2 import Stage2Config

    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: refit checkpoint not found")
    ck = torch.load(path, map_location="cpu", weights_only=False)
    cfg = Stage2Config.from_mapping(ck["config"])
    base = cfg.build(ck["d"], ck["n_u"], inertia)
    base.load_state_dict(ck["base_state_dict"])
    if not ck["terms"] and not ck["time_channel"]:
        return base.eval(), ck
    terms = [ScaledTerm(term_from_spec(dict(sp["inner"])), sp["scale"]) for sp in ck["terms"]]
    model = RefitModel(base, terms, time_channel=ck["time_channel"])
    model.load_state_dict(ck["state_dict"])
    return model.eval(), ck
