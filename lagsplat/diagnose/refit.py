"""How far the gap shrinks: refit Stage 2 with the diagnosed effect and measure the held-out gap.

Refit
-----
The winning effect(s) of :func:`lagsplat.diagnose.select_effect` become
energy-consistent torch terms (:func:`lagsplat.diagnose.terms.build_term`)
added to the Lagrangian (:class:`~lagsplat.diagnose.refit_terms.RefitModel`, an
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
which this module does not run (:attr:`RefitSpec.not_refit <lagsplat.diagnose.refit_terms.RefitSpec.not_refit>`).

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
plus white noise at the chart's level (:func:`lagsplat.diagnose.filters.chart_noise`,
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
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import torch
from torch import nn

from lagsplat.diagnose.effect_terms import EffectTerm
from lagsplat.diagnose.refit_terms import RefitModel, RefitSpec, model_chart, refit_spec
from lagsplat.diagnose.terms import AugmentedLagrangian
from lagsplat.diagnose.settings import RefitConfig

__all__ = [
    "RefitConfig",
    "RefitResult",
    "refit",
    "add_control",
    "GAP_METRICS",
]

#: The gap numbers compared before / after (name -> lower is better).
GAP_METRICS = ("eps_q", "eps_freq", "envelope_decay_error", "image_excess", "eps_q_over_floor", "eps_freq_over_floor")




@dataclass
class RefitResult:
    """A refit model with the chart it reads.

    Attributes:
        model: the refit model (:class:`~lagsplat.diagnose.refit_terms.RefitModel`, or the plain Lagrangian for a pure delay).
        chart: the chart it is evaluated on (:func:`~lagsplat.diagnose.refit_terms.model_chart`).
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
        diagnosis: the :class:`~lagsplat.diagnose.diagnosis.Diagnosis`.
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
    of :class:`~lagsplat.models.inertia.CholeskyField` set to that Cholesky factor,
    weights zero). Exact where the fitted field is constant; in practice it can have
    collapsed (``L_C L_C^T`` near zero, as the floor already over-damps), and there its
    gradient vanishes (softplus far below zero), so without this the fine-tune starts
    ``g`` times less damped and cannot raise the damping again: its free rollouts run
    fast with swings too large (the blind suite's end-stop clips,
    ``docs/experiments/diagnosis_history.md``).
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
        result: the refit (from :func:`refit` or :func:`~lagsplat.diagnose.refit_choice.choose_by_refit`); modified in place.
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
