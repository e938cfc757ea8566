"""Which significant candidate to refit: the Delta-BIC winner, confirmed by its refit's training-rollout error (paper §3.3 model selection)."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

from torch import nn

from lagsplat.diagnose.reading import INDISTINGUISHABLE
from lagsplat.diagnose.refit import RefitConfig, RefitResult, refit
from lagsplat.diagnose.select import signature_confirmed

__all__ = ["choose_by_refit"]


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
    makes the model follow its own training video worse, and only in favour of a rival the residual does not
    reject by very strong evidence (within ``min_delta_bic`` of the winner's: a stiff end stop, hard to refit,
    can lead a drift by far, as on a rendered torsion disk: ``docs/experiments/code_comment_history.md``).
    A missing degree of freedom, which no refit can
    confirm, gives way to a significant rival with a Stage-2 remedy that the residual cannot tell apart from
    it (evidence within 2) when that rival's refit beats the identified model. Neither does it overrule a winner that its
    own chart-invariant signature confirms (:func:`~lagsplat.diagnose.select.signature_confirmed`: a
    linear envelope and an off-centre rest for dry friction). Held-out frames are not read. Applies when
    there is one accepted effect (``max_effects = 1``, the default) and at least two
    significant candidates with a Stage-2 refit (a missing degree of freedom has
    none and is never compared).

    Args:
        chart, model, stage2_cfg, inertia: as for :func:`refit`.
        diagnosis: the :class:`~lagsplat.diagnose.diagnosis.Diagnosis`.
        baseline_nrmse: the identified model's training-rollout NRMSE (Stage-2
            ``selected_nrmse``); ``None``: nothing is compared.
        cfg: refit settings (its ``control`` is ignored here).

    Returns:
        ``(diagnosis, candidates, result)``: the diagnosis with the chosen effect as
        its winner (the input itself when the winner stands or nothing is compared),
        one record per candidate refit (``effect``, ``delta_bic``, ``train_rollout_nrmse``,
        ``beats_identified``: below ``baseline_nrmse``, ``chosen``), empty when nothing was compared, and the
        chosen effect's refit without its control (:func:`~lagsplat.diagnose.refit.add_control` adds it;
        ``None`` when nothing was compared).
    """
    cfg = cfg or RefitConfig()
    effects = list(getattr(diagnosis, "effects", []))
    refittable = [f for f in diagnosis.ranking if f.significant and f.effect != "missing_dof"]
    if baseline_nrmse is not None and len(effects) == 1 and effects[0].effect == "missing_dof":
        return _rival_of_a_missing_dof(chart, model, stage2_cfg, diagnosis, baseline_nrmse, cfg, inertia, refittable)
    if baseline_nrmse is None or len(effects) != 1 or len(refittable) < 2:
        return diagnosis, [], None
    min_bic = float(diagnosis.settings.get("min_delta_bic", 10.0))
    if signature_confirmed(effects[0], min_bic):
        return diagnosis, [], None  # its own signature confirms the winner: no rival's rollout error overrules it
    refittable = [f for f in refittable if f.effect == effects[0].effect or f.evidence >= effects[0].evidence - min_bic]
    if len(refittable) < 2:
        return diagnosis, [], None  # the residual prefers the winner by very strong evidence: a refit does not overrule it
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



def _rival_of_a_missing_dof(
    chart: Any, model: nn.Module, stage2_cfg: Any, diagnosis: Any, baseline_nrmse: float, cfg: RefitConfig, inertia: Any,
    refittable: list[Any],
) -> tuple[Any, list[dict[str, Any]], RefitResult | None]:
    """A missing degree of freedom has no Stage-2 remedy, so no refit can confirm it. A significant rival that
    has one and that the residual cannot tell apart from it (evidence within :data:`INDISTINGUISHABLE`) is refit,
    and taken when its refit follows the training video better than the identified model; otherwise the
    missing degree of freedom stands (``rows`` records the rival's refit either way)."""
    first = diagnosis.effects[0]
    close = [f for f in refittable if f.evidence >= first.evidence - INDISTINGUISHABLE]
    if not close:
        return diagnosis, [], None
    rival = close[0]
    r = refit(chart, model, stage2_cfg, dataclasses.replace(diagnosis, winner=rival.effect, effects=[rival]), dataclasses.replace(cfg, control=False), inertia)
    err = float(r.history.get("selected_nrmse", math.inf)) if r is not None else math.inf
    beats = err < baseline_nrmse
    rows = [{"effect": first.effect, "delta_bic": float(first.delta_bic), "train_rollout_nrmse": None, "beats_identified": None, "chosen": not beats},
            {"effect": rival.effect, "delta_bic": float(rival.delta_bic), "train_rollout_nrmse": err, "beats_identified": beats, "chosen": beats}]  # fmt: skip
    if not beats:
        return diagnosis, rows, None
    return dataclasses.replace(diagnosis, winner=rival.effect, effects=[rival]), rows, r
