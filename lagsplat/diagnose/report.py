"""The sim-to-real gap report of one trained system.

:func:`diagnose_system` reads the artifacts of ``results/<system>/`` (``clip.npz``,
``stage1.pt``, ``chart.npz``, ``stage2.pt``, ``metrics.json``) and writes
``diagnosis/``:

* ``report.json``: the verdict (``"cannot_diagnose"`` with its reason in
  ``verdict_text`` when the chart fails its checks, :func:`reliability`; the
  residual's ranking is kept in ``residual_ranking`` and the evidence), the evidence (:meth:`Diagnosis.to_dict
  <lagsplat.diagnose.diagnosis.Diagnosis.to_dict>`: every candidate's fit with
  coefficients and standard errors, ``Delta BIC``, ``R2``, CV gain, the
  signatures), what the recording can and cannot tell (``identifiability``,
  :func:`~lagsplat.diagnose.identifiability.identifiability`; ``None`` with
  "cannot_diagnose"), where the gap shows (:mod:`lagsplat.diagnose.where`), the
  held-out gap before and after the refit (:mod:`lagsplat.diagnose.refit`), the
  refit terms and the energy check, the settings and which frames were used
  for what;
* ``report.md``: the same for a reader;
* ``figures/where_{time,state,latent,image}.png``, ``figures/gap.png``
  (held-out free rollouts before / after against the encoded video) and
  ``figures/backbone.png`` (frequency and damping ratio against amplitude, the
  video's swings against the models' free releases; ``report.json``'s ``backbone``,
  :mod:`lagsplat.diagnose.backbone`);
* ``refit.pt`` when a refit was made (:func:`lagsplat.diagnose.refit_io.load_refit`).

Frames: the diagnosis (residual, selection) and the localisation read the
*training* frames only (``diagnose.split``); the refit reads the training
frames (windows and model selection, as Stage 2); the held-out frames are
read only by the gap measurement (the backbone figure draws their swings too,
deciding nothing). A clip identified on all its frames
(:attr:`lagsplat.io.clip.Clip.no_held_out`) has none: the ranking is read off
the training residual as usual, ``report.json``'s ``held_out`` carries the
clip's note, and the held-out gap and the refit it validates are skipped, saying so.

The steps live beside it: the diagnosis (:func:`lagsplat.diagnose.diagnose_chart`),
the localisation (:mod:`lagsplat.diagnose.localise`), the refit
(:mod:`lagsplat.diagnose.refit`, :mod:`lagsplat.diagnose.refit_choice`), the
gap (:mod:`lagsplat.diagnose.gap`, :mod:`lagsplat.diagnose.gap_plot`), the
checks on the verdict (:mod:`lagsplat.diagnose.report_checks`) and the
Markdown (:mod:`lagsplat.diagnose.markdown`); :func:`render_markdown`,
:func:`plot_gap`, :func:`reliability` and :func:`held_out_check` are
importable from here too.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lagsplat.artifacts import DIAGNOSIS_FIGURES, DIAGNOSIS_FILES, Artifacts
from lagsplat.diagnose import diagnose_chart
from lagsplat.diagnose.quantities import report_quantities
from lagsplat.diagnose.backbone import backbone
from lagsplat.diagnose.backbone_plot import plot_backbone
from lagsplat.diagnose.gap import (
    common_noise_floor,
    energy_check,
    gap_reduction,
    held_out_gap,
)
from lagsplat.diagnose.gap_plot import plot_gap
from lagsplat.diagnose.identifiability import identifiability
from lagsplat.diagnose.localise import localise
from lagsplat.diagnose.pixels import add_pixel_sizes
from lagsplat.diagnose.markdown import GAP_LABELS, render_markdown
from lagsplat.diagnose.refit import (
    GAP_METRICS,
    RefitResult,
    add_control,
    refit,
)
from lagsplat.diagnose.refit_choice import choose_by_refit
from lagsplat.diagnose.refit_io import load_refit, save_refit
from lagsplat.diagnose.refit_terms import refit_spec
from lagsplat.diagnose.report_checks import held_out_check, reliability, stopped_run_report
from lagsplat.diagnose.where import split_code
from lagsplat.diagnose.where_plots import plot_where
from lagsplat.io.atomic import atomic_write, write_json
from lagsplat.io.clip import HELD_OUT, ClipError
from lagsplat.io.common import jsonable
from lagsplat.diagnose.settings import DiagnoseConfig

#: ``report.json``'s verdict when the chart fails its checks (:func:`reliability`): no finding is read off it.
CANNOT_DIAGNOSE = "cannot_diagnose"

__all__ = ["CANNOT_DIAGNOSE", "DiagnoseConfig", "diagnose_system", "diagnose_artifacts", "render_markdown", "write_report", "plot_gap", "reliability", "held_out_check"]




@dataclass
class _Run:
    """The inputs of one :func:`diagnose_artifacts` call that its steps share."""

    clip: Any | None
    ae: Any | None
    chart: Any
    model: Any
    stage2_cfg: Any | None
    cfg: DiagnoseConfig
    eval_cfg: Any
    inertia: Any | None
    progress: bool
    stage2_history: Mapping[str, Any] | None
    out: Path
    source: str

    def gap(self, chart: Any, model: Any) -> dict[str, Any]:
        """:func:`~lagsplat.diagnose.gap.held_out_gap` of ``model`` reading ``chart``."""
        return held_out_gap(chart, model, self.clip, self.ae, self.eval_cfg, self.source)


def _gap_record(before: dict[str, Any], metrics_json: Mapping[str, Any] | None) -> dict[str, Any]:
    """The report's ``gap`` record before any refit, cross-checked against ``metrics.json`` when given."""
    gap: dict[str, Any] = {
        "definition": {k: GAP_LABELS[k] for k in GAP_METRICS} | {
            "frames": "the held-out frames only (longest held-out segment, protocol of lagsplat.evaluate); "
            "neither the diagnosis nor the refit read them",
            "reduction": "1 - after / before (positive: the gap shrank)",
        },
        "before": before, "after": None, "control": None, "reduction": None, "reduction_vs_control": None,
    }  # fmt: skip
    if metrics_json and "metrics" in metrics_json and "eps_q" in metrics_json["metrics"]:
        ref = float(metrics_json["metrics"]["eps_q"]["value"])
        gap["metrics_json_eps_q"] = ref
        gap["before_matches_metrics_json"] = bool(abs(ref - before["eps_q"]) <= 1e-6 + 1e-4 * abs(ref))
    return gap


def _no_refit_reason(run: _Run, diag: Any) -> str | None:
    """Why no refit is made (``None``: one is)."""
    stage1 = reliability(run.chart)  # the Stage-1 checks only: a refit on a chart that fails them means nothing
    if not stage1["reliable"]:
        return "cannot diagnose: no refit on a chart that fails its checks"
    if diag.winner == "none":
        return "nothing significant: no refit"
    if not run.cfg.refit.enabled:
        return "refit disabled (diagnose.refit.enabled=false)"
    if run.stage2_cfg is None:
        return "no Stage-2 settings given: no refit"
    return None


def _make_refit(run: _Run, diag: Any, refit_rec: dict[str, Any], timings: dict[str, float]) -> tuple[Any, RefitResult | None]:
    """Choose the effect by its refit (:attr:`RefitConfig.choose`), refit it and run the control: ``(diagnosis, refit or None)``."""
    rc = run.cfg.refit
    chosen = None
    if rc.choose:
        t1 = time.perf_counter()
        base = (run.stage2_history or {}).get("selected_nrmse")
        base = None if base is None else float(base)
        diag, choice, chosen = choose_by_refit(run.chart, run.model, run.stage2_cfg, diag, base, rc, run.inertia)
        refit_rec["baseline_train_rollout_nrmse"] = base
        if choice:
            refit_rec["choice"] = choice
            timings["choice_s"] = time.perf_counter() - t1
    if chosen is not None:  # the chosen effect's refit is made: only its control is left to run
        r = add_control(chosen, run.chart, run.model, run.stage2_cfg, rc, run.inertia, run.progress) if rc.control else chosen
    else:
        r = refit(run.chart, run.model, run.stage2_cfg, diag, rc, run.inertia, run.progress)
    return diag, r


def _score_refit(run: _Run, r: RefitResult, gap: dict[str, Any], runs: dict[str, tuple[Any, Any]], refit_rec: dict[str, Any]) -> None:
    """The held-out gap after the refit and of its control, over one noise floor; the refit record; ``refit.pt`` written."""
    after = run.gap(r.chart, r.model)
    ctrl = None if r.control is None else run.gap(run.chart, r.control)
    before, after, ctrl = common_noise_floor(gap["before"], after, ctrl)  # compared over one chart-noise floor
    gap.update(before=before, after=after, reduction=gap_reduction(before, after))
    runs[f"refit with {', '.join(r.spec.effects)} (after)"] = (r.model, r.chart)
    if ctrl is not None:
        gap["control"] = ctrl
        gap["reduction_vs_control"] = gap_reduction(ctrl, after)
        runs["same fine-tune without the term (control)"] = (r.control, run.chart)
    gap["held_out_check"] = held_out_check(gap, r.spec.effects)
    refit_rec.update(
        done=True, spec=r.spec.to_dict(), fitted_terms=r.fitted_terms, energy_check=energy_check(r.model, r.chart),
        selected_epoch=r.history.get("selected_epoch"), selected_train_nrmse=r.history.get("selected_nrmse"),
        control_selected_train_nrmse=None if r.control_history is None else r.control_history.get("selected_nrmse"),
        checkpoint=DIAGNOSIS_FILES["refit"],
    )  # fmt: skip
    save_refit(run.out / DIAGNOSIS_FILES["refit"], r, run.stage2_cfg)


def _refit_step(run: _Run, diag: Any, gap: dict[str, Any], runs: dict[str, tuple[Any, Any]], timings: dict[str, float]) -> tuple[Any, dict[str, Any]]:
    """Refit with the diagnosed effect when there is one and settings allow: ``(diagnosis, refit record)``; updates ``gap`` and ``runs``."""
    refit_rec: dict[str, Any] = {"done": False}
    reason = _no_refit_reason(run, diag)
    if reason is not None:
        refit_rec["reason"] = reason
        return diag, refit_rec
    diag, r = _make_refit(run, diag, refit_rec, timings)
    if r is None:
        sp = refit_spec(diag, run.model, run.cfg.refit.init)
        refit_rec.update(reason="no Stage-2 remedy for the effect(s) found", spec=sp.to_dict())
    else:
        try:
            _score_refit(run, r, gap, runs, refit_rec)
        except ClipError as e:  # the refit's chart reads the held-out part differently (a shorter period): no gap to score it on
            refit_rec.update(reason=f"the refit was made but its held-out gap cannot be scored ({e})", spec=r.spec.to_dict())
    return diag, refit_rec


def _gap_figure(run: _Run, runs: dict[str, tuple[Any, Any]], figures: dict[str, str], refit_done: bool, title: str) -> None:
    """Remove what an earlier run left that no longer applies (its ``refit.pt``, its figures) and draw the gap figure."""
    out, fig_dir = run.out, run.out / "figures"
    if not refit_done and (out / DIAGNOSIS_FILES["refit"]).exists():  # a refit of an earlier run no longer applies
        (out / DIAGNOSIS_FILES["refit"]).unlink()
    p = plot_gap(run.chart, runs, fig_dir / DIAGNOSIS_FIGURES["gap"], title, run.eval_cfg.sigma)
    if p is not None:
        figures["gap"] = str(Path(p).relative_to(out))
    for fname in DIAGNOSIS_FIGURES.values():  # figures of an earlier run that no longer apply
        f = fig_dir / fname
        if f.exists() and f"figures/{fname}" not in figures.values():
            f.unlink()


def _backbone_step(run: _Run, res: Any, refit_rec: Mapping[str, Any], figures: dict[str, str], title: str) -> dict[str, Any]:
    """The backbone record (:func:`~lagsplat.diagnose.backbone.backbone`) of the video, the identified model and the
    refit model when one was saved (``refit.pt``), and its figure; an earlier run's figure is removed when none is drawn."""
    models: dict[str, tuple[Any, bool]] = {"identified model": (run.model, False)}
    note = None
    if refit_rec.get("done"):
        try:
            m, ck = load_refit(run.out / DIAGNOSIS_FILES["refit"], run.inertia)
            models["refit model"] = (m, bool(ck.get("time_channel", False)))
        except (FileNotFoundError, KeyError, RuntimeError) as e:  # the refit stands; only its backbone is missing
            note = f"the refit model could not be reloaded ({e})"
    rec = backbone(run.chart, res, models)
    if note:
        rec["note"] = note
    path = run.out / "figures" / DIAGNOSIS_FIGURES["backbone"]
    if plot_backbone(rec, path, title) is not None:
        figures["backbone"] = str(path.relative_to(run.out))
    else:
        path.unlink(missing_ok=True)
    return rec


def _report_record(
    run: _Run, diag: Any, where: Any, gap: dict[str, Any], refit_rec: dict[str, Any], figures: dict[str, str], which: int | None,
    timings: dict[str, float], title: str, system: str, backbone_rec: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """The content of ``report.json`` (JSON-ready)."""
    chart, cfg = run.chart, run.cfg
    n_which = sum(len(s) for s in (chart.segments(which) if which is not None else [np.arange(len(chart.t))]))
    rel = reliability(chart, run.stage2_history, diag)
    ranked = "nothing significant" if diag.winner == "none" else ", ".join(diag.labels)
    verdict, text = (diag.winner, ranked) if rel["reliable"] else (CANNOT_DIAGNOSE, "cannot diagnose: " + "; ".join(rel["reasons"]))
    note = getattr(run.clip, "no_held_out", None)
    drawn = any(((backbone_rec or {}).get("video") or {}).get("held_out", []))  # held-out swings in the backbone figure
    report = {
        "system": system, "title": title, "verdict": verdict, "verdict_text": text,
        "held_out": note,  # None: the held-out frames score the gap; a string: the clip has none (Clip.no_held_out)
        "residual_ranking": {"winner": diag.winner, "text": ranked},  # what the residual says; the verdict only when reliable
        "reliability": rel,
        "summary": diag.summary(),
        "diagnosis": diag.to_dict(),
        # what the recording determines and what would settle the rest; none on a chart that supports no diagnosis
        "identifiability": identifiability(diag.to_dict(), gap) if rel["reliable"] else None,
        "where": where.summary(),
        "gap": gap,
        "refit": refit_rec,
        "figures": figures,
        "backbone": backbone_rec,  # frequency and damping ratio against amplitude (lagsplat.diagnose.backbone)
        "frames": {
            "diagnosis_split": cfg.split, "n_diagnosis_frames": int(n_which),
            "n_held_out_frames": int(np.sum(np.asarray(chart.split) == HELD_OUT)),
            "held_out_used_for": ("the gap only (before / after / control)" if note is None else f"nothing ({note})")
            + ("; their swings are drawn in the backbone figure, which decides nothing" if drawn else ""),
        },
        "config": cfg.to_dict(),
        "timings": timings,
    }  # fmt: skip
    return jsonable(report)


def diagnose_artifacts(
    clip: Any | None, ae: Any | None, chart: Any, model: Any, stage2_cfg: Any | None, out_dir: str | Path,
    cfg: DiagnoseConfig | None = None, eval_cfg: Any | None = None, title: str = "", system: str = "", inertia: Any | None = None,
    metrics_json: Mapping[str, Any] | None = None, progress: bool = False, stage2_history: Mapping[str, Any] | None = None,
    scale: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Diagnose, localise, refit and measure the held-out gap; write ``report.json``, ``report.md`` and the figures.

    Args:
        clip: the clip (frames for the image maps and image error), or ``None`` (latent only).
        ae: the Stage-1 autoencoder, or ``None`` (latent only).
        chart: the chart.
        model: the fitted model (Stage 2).
        stage2_cfg: the :class:`~lagsplat.train.stage2.Stage2Config` the model was fitted
            with (``None``: no refit).
        out_dir: the ``diagnosis/`` folder.
        cfg: settings.
        eval_cfg: :class:`lagsplat.evaluate.EvalConfig` of the gap (default settings).
        title, system: names for the report.
        inertia: decoder inertia (``stage2.mass=decoder``).
        metrics_json: the system's ``metrics.json`` (cross-check of the "before" numbers).
        progress: tqdm bars of the refit.
        stage2_history: the Stage-2 training history (``selected_nrmse`` enters :func:`reliability`).
        scale: ``system.scale`` (a known length in the image): the identified quantities in physical units
            (:mod:`lagsplat.diagnose.units`).

    Returns:
        The report (the content of ``report.json``).

    Raises:
        ValueError: a ``scale`` with coinciding points or with only one of ``points`` and ``metres``
            (:func:`~lagsplat.diagnose.units.metres_per_source_px`), before any work.
    """
    from lagsplat.diagnose.units import metres_per_source_px
    from lagsplat.evaluate import EvalConfig

    metres_per_source_px(scale)  # a malformed scale stops here, before the work

    cfg = cfg or DiagnoseConfig()
    run = _Run(clip, ae, chart, model, stage2_cfg, cfg, eval_cfg or EvalConfig(), inertia, progress, stage2_history, Path(out_dir),
               f"{system or 'system'} held-out frames")  # fmt: skip
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    which = split_code(cfg.split)
    diag, res = diagnose_chart(model, chart, which, cfg.sigma, **cfg.select)
    timings["diagnosis_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    where = localise(model, chart, res, None if clip is None else clip.images, ae, cfg.where, which)
    figures = {k: str(Path(v).relative_to(run.out)) for k, v in plot_where(where, run.out / "figures", title or system).items()}
    timings["where_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    runs = {"identified model (before)": (model, chart)}
    note = getattr(clip, "no_held_out", None)  # a clip identified on all its frames (lagsplat.io.clip.Clip.no_held_out)
    try:
        if note is not None:
            raise ClipError(f"{note}: the clip was identified on all its frames")
        gap = _gap_record(run.gap(chart, model), metrics_json)
    except ClipError as e:  # the diagnosis reads the training frames only: it stands without a held-out gap
        gap = {"unavailable": str(e), "before": None, "after": None, "control": None, "reduction": None, "reduction_vs_control": None}
        why = f"{note}: the held-out refit validation is skipped" if note is not None else f"no held-out gap to score a refit on ({e})"
        refit_rec = {"done": False, "reason": why}
        (run.out / DIAGNOSIS_FILES["refit"]).unlink(missing_ok=True)  # an earlier run's refit no longer applies
        for fname in DIAGNOSIS_FIGURES.values():  # figures of an earlier run that no longer apply
            if f"figures/{fname}" not in figures.values():
                (run.out / "figures" / fname).unlink(missing_ok=True)
    else:
        diag, refit_rec = _refit_step(run, diag, gap, runs, timings)
        _gap_figure(run, runs, figures, refit_rec["done"], title or system)
    timings["gap_and_refit_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    backbone_rec = _backbone_step(run, res, refit_rec, figures, title or system)
    timings["backbone_s"] = time.perf_counter() - t0
    screen = None
    if ae is not None:  # the effect's size in pixels of the video, through the decoder
        from lagsplat.diagnose.screen import ScreenKinematics

        screen = ScreenKinematics.from_autoencoder(ae, chart)
        add_pixel_sizes(diag, screen, getattr(clip, "meta", None))

    report = _report_record(run, diag, where, gap, refit_rec, figures, which, timings, title, system, backbone_rec)
    # the identified frequency, damping and the named effect's coefficients, each with its 90 % interval
    report["identified"] = jsonable(report_quantities(metrics_json, report, screen, chart, clip, scale))
    write_report(report, run.out)
    return report


def diagnose_system(
    artifacts: Artifacts | str | Path, cfg: DiagnoseConfig | None = None, eval_cfg: Any | None = None, title: str = "", progress: bool = False,
    scale: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """:func:`diagnose_artifacts` on the artifacts of one run.

    Args:
        artifacts: the run's :class:`~lagsplat.artifacts.Artifacts` (``clip.npz``, ``stage1.pt``,
            ``chart.npz``, ``stage2.pt``, optional ``metrics.json``; the report goes to
            ``artifacts.diagnosis``), or a ``results/<system>/`` folder in the standard layout.
        cfg, eval_cfg, title, progress, scale: see :func:`diagnose_artifacts`.

    Returns:
        The report.

    A run an earlier stage stopped (its ``stopped.json``, :meth:`~lagsplat.artifacts.Artifacts.load_stopped`:
    ingest refused the clip, Stage 2 refused a chart that failed the quality gate, ...) gets the verdict
    "cannot diagnose" with that stage's reason (:func:`~lagsplat.diagnose.report_checks.stopped_report`);
    so does a run stopped at the chart-quality gate without that record (no ``stage2.pt``, the chart
    failing its checks; :func:`~lagsplat.diagnose.report_checks.no_model_report`).

    Raises:
        FileNotFoundError: naming the first missing artifact (no stop recorded).
    """
    from lagsplat.train.stage2 import Stage2Config

    a = artifacts if isinstance(artifacts, Artifacts) else Artifacts.at(artifacts)
    stopped = stopped_run_report(a, title)  # an earlier stage stopped: ingest refused the clip, Stage 2 the chart, ...
    if stopped is not None:
        return stopped
    a.require("stage2")
    clip, ae, chart = a.load_clip(), a.load_stage1(), a.load_chart()
    model, ck = a.load_stage2()
    s2 = Stage2Config.from_mapping(ck["config"])
    inertia = None
    if s2.mass == "decoder":
        from lagsplat.models.inertia import DecoderInertia

        inertia = DecoderInertia.from_decoder(ae.decoder, chart.W_inv, chart.mean, chart.height, chart.width)
    mj = a.load_metrics()
    name = a.system_dir.name
    return diagnose_artifacts(
        clip, ae, chart, model, s2, a.diagnosis, cfg, eval_cfg,
        title or (mj or {}).get("title", name), name, inertia, mj, progress, ck.get("history"), scale,
    )  # fmt: skip


def write_report(report: Mapping[str, Any], out_dir: str | Path) -> tuple[Path, Path]:
    """Write ``report.json`` and ``report.md`` under ``out_dir`` atomically; returns their paths."""
    out = Path(out_dir)
    pj = write_json(out / DIAGNOSIS_FILES["report_json"], report)
    pm = out / DIAGNOSIS_FILES["report_md"]
    with atomic_write(pm) as tmp:
        tmp.write_text(render_markdown(report))
    return pm, pj
