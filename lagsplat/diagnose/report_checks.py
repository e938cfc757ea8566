"""Trust in the verdict: whether the upstream artifacts support a diagnosis, and whether the held-out gap confirms it.

:func:`reliability` checks the chart and the identified model before the
verdict is read (paper §3.2 chart, §3.3 model selection); :func:`held_out_check`
states whether the refit with the diagnosed effect shrinks the held-out gap
beyond what the same fine-tune without it does. Both are statements in the
report (:mod:`lagsplat.diagnose.report`), never choices: the held-out frames
decide nothing upstream.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from lagsplat.diagnose.markdown import fmt_pct

__all__ = ["reliability", "CHECK_METRICS", "CAUTION_MEANING", "held_out_check", "no_model_report", "stopped_report", "stopped_run_report"]

#: What each failed caution of :func:`reliability` means, in the report's words
CAUTION_MEANING = {
    "model_follows_training": "the identified model misses much of the training motion (a strong unmodelled effect, "
    "a Stage-2 failure or a distorted chart; the evidence below cannot tell these apart unless a candidate explains the residual)",
    "residual_explained": "the residual stays well above the chart noise after the model-class corrections and any effect found "
    "(the model misfits within its own class, e.g. a distorted chart, or the effect is not in the library)",
}


def reliability(chart: Any, stage2_history: Mapping[str, Any] | None = None, diagnosis: Any | None = None) -> dict[str, Any]:
    """Whether the upstream artifacts are good enough for the diagnosis to mean anything.

    A residual is only the sign of an unmodelled effect when the chart follows the
    object and the model follows the chart; otherwise any candidate may win (or
    none). Checks:

    * ``chart_gate``: when the chart carries the chart-quality gate's result
      (``chart.meta["gate"]``, :func:`lagsplat.chart.gate.chart_gate`: continuity,
      decoder motion, coverage of the moving pixels, encoder saturation), it
      passed; its failed checks are the reasons. A chart from before the gate
      is read by the two older checks instead:
    * ``chart_continuous``: the chart's jump statistic (``chart.meta["continuity_jump_ratio"]``,
      :func:`lagsplat.chart.chart_continuity`) below :data:`lagsplat.chart.FOLD_WARNING`;
    * ``decoder_shows_motion``: the image change of one standard deviation of ``q``
      along the most visible direction, ``lambda_max(G_bar)`` (the chart is
      whitened), exceeds the AE floor on the training frames;
    * ``model_follows_training``: the Stage-2 model-selection NRMSE (free rollouts of
      ``select_periods`` periods on training frames) below 0.5;
    * ``residual_explained``: the residual left after the model-class corrections
      and the accepted effects is within ``unexplained_excess`` times the chart
      noise (:func:`~lagsplat.diagnose.select_effect`, ``null["unexplained"]``).

    The Stage-1 checks make the verdict ``reliable``; when one fails, the report's
    verdict is "cannot diagnose" (:func:`lagsplat.diagnose.report.diagnose_artifacts`). The last two are
    cautions: a model that does not follow its training video, or a residual
    nothing explains, may come from a Stage-2 failure or a distorted chart, but
    also from a strong unmodelled effect (a missing degree of freedom does both),
    or one outside the library.

    Returns:
        ``{"reliable": bool, "checks": {name: {"ok", "value", "threshold", "text"}},
        "reasons": [str] (failed gates), "cautions": [str] (failed cautions)}``.
    """
    from lagsplat.chart import FOLD_WARNING

    checks: dict[str, dict[str, Any]] = {}
    meta = chart.meta if isinstance(chart.meta, Mapping) else {}
    gate = meta.get("gate")
    if gate is not None:  # the chart-quality gate supersedes the older jump ratio, which reads an impact as a tear
        failed = list(gate.get("reasons", []))
        checks["chart_gate"] = {"ok": bool(gate.get("passed")), "value": float(len(failed)), "threshold": 0.0,
                                "text": "failed checks of the chart-quality gate", "reasons": failed}  # fmt: skip
    jump = meta.get("continuity_jump_ratio") if gate is None else None
    if jump is not None:
        checks["chart_continuous"] = {"ok": bool(jump < FOLD_WARNING), "value": float(jump), "threshold": FOLD_WARNING,
                                      "text": "chart jump ratio (max |2nd difference| / median |1st difference|)"}  # fmt: skip
    lam = float(np.linalg.eigvalsh(0.5 * (chart.G_bar + chart.G_bar.T)).max())
    floor = float(chart.ae_floor_train)
    if floor > 0 and gate is None:
        checks["decoder_shows_motion"] = {"ok": bool(lam > floor), "value": lam / floor, "threshold": 1.0,
                                          "text": "image MSE of one standard deviation of q / AE floor"}  # fmt: skip
    if stage2_history and stage2_history.get("selected_nrmse") is not None:
        v = float(stage2_history["selected_nrmse"])
        checks["model_follows_training"] = {"ok": bool(math.isfinite(v) and v < 0.5), "value": v, "threshold": 0.5,
                                            "text": "Stage-2 selection NRMSE (free rollouts on training frames)"}  # fmt: skip
    if diagnosis is not None:
        null = diagnosis.null
        checks["residual_explained"] = {"ok": not bool(null.get("unexplained")), "value": float(null.get("excess_after_effects", null["excess_over_noise"])),
                                        "threshold": float(diagnosis.settings.get("unexplained_excess", 4.0)) if isinstance(diagnosis.settings, Mapping) else 4.0,
                                        "text": "residual variance left / chart-noise variance"}  # fmt: skip
    def why(k: str) -> str:
        return f"{checks[k]['text']} = {checks[k]['value']:.3g} (need {'>' if k == 'decoder_shows_motion' else '<'} {checks[k]['threshold']:g})"

    reasons = [f"chart-quality gate {r}" for r in checks.get("chart_gate", {}).get("reasons", [])]
    reasons += [why(k) for k in ("chart_continuous", "decoder_shows_motion") if k in checks and not checks[k]["ok"]]
    cautions = [f"{why(k)}: {CAUTION_MEANING[k]}" for k in ("model_follows_training", "residual_explained") if k in checks and not checks[k]["ok"]]
    return {"reliable": not reasons, "checks": checks, "reasons": reasons, "cautions": cautions}


#: Gap metrics the held-out check reads (the trajectory and the image; frequency and envelope are reported beside).
CHECK_METRICS = ("eps_q", "image_excess")

#: Smallest relative change of a gap metric that counts (a smaller one prints as "+0 %")
MIN_RELATIVE_CHANGE = 0.01

#: A change of eps_q counts only beyond this many standard deviations of the chart-noise floor
FLOOR_SDS = 2.0


def _beyond_floor(gap: Mapping[str, Any], key: str, ref: str) -> bool:
    """Whether the refit's ``key`` is below ``gap[ref]``'s by more than the noise: :data:`MIN_RELATIVE_CHANGE`,
    and for ``eps_q`` also :data:`FLOOR_SDS` standard deviations of the chart-noise floor (``before["floor"]["eps_q_sd"]``)."""
    b, a = (gap.get(ref) or {}).get(key), (gap.get("after") or {}).get(key)
    if b is None or a is None or not (math.isfinite(b) and math.isfinite(a)) or b <= 0:
        return False
    sd = ((gap.get("before") or {}).get("floor") or {}).get(f"{key}_sd")
    floor_ok = sd is None or not math.isfinite(sd) or (b - a) > FLOOR_SDS * sd
    return bool((b - a) / b >= MIN_RELATIVE_CHANGE and floor_ok)


def held_out_check(gap: Mapping[str, Any], effects: Sequence[str]) -> dict[str, Any] | None:
    """Whether the refit with the diagnosed effect(s) shrinks the held-out gap: a statement, never a choice.

    Confirmed when, for each of :data:`CHECK_METRICS`, the refit model's held-out gap is
    below the identified model's and below the control fine-tune's (same settings, no term),
    so that what the term buys is not what more training buys, each by more than the noise:
    :data:`MIN_RELATIVE_CHANGE` (1 %) and, for ``eps_q``, :data:`FLOOR_SDS` standard deviations
    of the chart-noise floor (:func:`~lagsplat.diagnose.gap.noise_floor`). The held-out frames
    decide nothing upstream: the verdict was taken on the training frames.

    Args:
        gap: the ``gap`` record of the report (``before``, ``after``, ``control``, ``reduction``,
            ``reduction_vs_control``).
        effects: names of the effects refit.

    Returns:
        ``{"confirmed", "text"}``, or ``None`` when no refit was scored.
    """
    red, red_c = gap.get("reduction") or {}, gap.get("reduction_vs_control") or {}
    vals = [red.get(k) for k in CHECK_METRICS] + ([red_c.get(k) for k in CHECK_METRICS] if gap.get("control") else [])
    if not red or any(v is None for v in vals):
        return None
    refs = ("before", "control") if gap.get("control") else ("before",)
    ok = all(_beyond_floor(gap, k, ref) for k in CHECK_METRICS for ref in refs)
    name = ", ".join(effects)
    nums = "; ".join(
        f"{k.replace('_', ' ')} {fmt_pct(red[k])} against the identified model"
        + (f", {fmt_pct(red_c[k])} against the same fine-tune without the term" if gap.get("control") else "")
        for k in CHECK_METRICS
    )
    text = (
        f"the refit with {name} shrinks the held-out gap ({nums})" if ok
        else f"the refit with {name} does not shrink the held-out gap beyond the chart noise and more training ({nums}): "
        "what the training frames point to is not confirmed on the held-out frames"
    )
    return {"confirmed": bool(ok), "text": text}


def no_model_report(chart: Any, system: str, title: str = "") -> tuple[dict[str, Any], str]:
    """``(report.json content, report.md text)`` of a run stopped before Stage 2 by a chart that fails its checks.

    Nothing but the chart's checks (:func:`reliability`) is read: there is no identified model
    to take a residual from. The verdict is ``"cannot_diagnose"`` with the reasons.

    Raises:
        ValueError: if the chart passes its checks (a run that stopped for another reason needs Stage 2 first).
    """
    rel = reliability(chart)
    if rel["reliable"]:
        raise ValueError(f"{system}: the chart passes its checks; run Stage 2 before the diagnosis")
    text = "cannot diagnose: " + "; ".join(rel["reasons"])
    rep = {"system": system, "title": title or system, "verdict": "cannot_diagnose", "verdict_text": text, "reliability": rel,
           "residual_ranking": None, "diagnosis": None, "gap": None, "refit": {"done": False, "reason": "no identified model: Stage 2 was not run"}}  # fmt: skip
    md = "\n".join([f"# Sim-to-real gap diagnosis: {title or system}", "", f"**Verdict: {text}.**", "",
                     "The run stopped before Stage 2 because the chart does not support a model, so there is no residual to read. "
                     "Improve Stage 1 first (a tighter crop, more steps or Gaussians; docs/preparation.md).", ""])  # fmt: skip
    return rep, md


#: What to do after each stage's stop, in the report's words
_STOP_ADVICE = {
    "ingest": "The clip was refused before any training; docs/preparation.md says what each reason means and which setting overrides it.",
    "views": "The novel views of this 3-D system could not be made; see docs/3d.md.",
    "stage1": "Stage 1 stopped; improve it first (a tighter crop, more steps or Gaussians; docs/preparation.md).",
    "chart": "The chart could not be built from Stage 1; improve Stage 1 first (docs/preparation.md).",
    "stage2": "When the chart failed its quality gate, improve Stage 1 first (a tighter crop, more steps or Gaussians; docs/preparation.md).",
}


def stopped_report(stop: Mapping[str, Any], system: str, title: str = "") -> tuple[dict[str, Any], str]:
    """``(report.json content, report.md text)`` of a run that an earlier stage stopped.

    ``stop`` is the stage's record (``stopped.json``, :meth:`lagsplat.artifacts.Artifacts.load_stopped`:
    ``stage``, ``reason``, ``time``): ingest refused the clip, or Stage 2 refused a chart that failed the
    chart-quality gate, ... No identified model exists, so nothing is read; the verdict is
    ``"cannot_diagnose"`` with the stage and its one-line reason (``stopped``: the record).
    """
    stage, reason = str(stop.get("stage", "?")), str(stop.get("reason", "")).strip() or "no reason recorded"
    text = f"cannot diagnose: the {stage} stage stopped: {reason}"
    rec = {k: stop.get(k) for k in ("stage", "reason", "time")}
    rep = {"system": system, "title": title or system, "verdict": "cannot_diagnose", "verdict_text": text, "stopped": rec,
           "reliability": None, "residual_ranking": None, "diagnosis": None, "gap": None,
           "refit": {"done": False, "reason": f"no identified model: the {stage} stage stopped"}}  # fmt: skip
    md = "\n".join([f"# Sim-to-real gap diagnosis: {title or system}", "", f"**Verdict: {text}.**", "",
                     f"The {stage} stage stopped{' at ' + str(stop['time']) if stop.get('time') else ''}, so there is no identified model "
                     "and no residual to read. " + _STOP_ADVICE.get(stage, ""), ""])  # fmt: skip
    return rep, md


def stopped_run_report(a: Any, title: str = "") -> dict[str, Any] | None:
    """Write the ``cannot_diagnose`` report of a run stopped before Stage 2 could give a model, or return ``None``.

    Stopped: a stage up to Stage 2 left its stop record (:meth:`lagsplat.artifacts.Artifacts.load_stopped`;
    :func:`stopped_report`), or there is no ``stage2.pt`` and the chart fails its checks (the gate's verdict
    without a record; :func:`no_model_report`). ``report.json`` and ``report.md`` are written atomically under
    ``a.diagnosis``.

    Args:
        a: the run's :class:`~lagsplat.artifacts.Artifacts`.
        title: the report's title (default the system's name).

    Returns:
        The report (``report.json``'s content), or ``None`` when the run was not stopped.

    Raises:
        FileNotFoundError: naming the first of ``clip.npz``, ``stage1.pt``, ``chart.npz`` missing when no stop is recorded.
    """
    from lagsplat.artifacts import DIAGNOSIS_FILES
    from lagsplat.io.atomic import atomic_write, write_json

    stop = a.load_stopped()
    if stop is not None:
        rep, md = stopped_report(stop, a.system_dir.name, title)
    else:
        a.require("clip", "stage1", "chart")
        if a.stage2.exists() or reliability(chart := a.load_chart())["reliable"]:
            return None
        rep, md = no_model_report(chart, a.system_dir.name, title)  # stopped at the chart-quality gate
    write_json(a.diagnosis / DIAGNOSIS_FILES["report_json"], rep)
    with atomic_write(a.diagnosis / DIAGNOSIS_FILES["report_md"]) as tmp:
        tmp.write_text(md)
    return rep
