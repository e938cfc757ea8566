"""The sim-to-real gap report of one trained system.

:func:`diagnose_system` reads the artifacts of ``results/<system>/`` (``clip.npz``,
``stage1.pt``, ``chart.npz``, ``stage2.pt``, ``metrics.json``) and writes
``diagnosis/``:

* ``report.json``: the verdict, the evidence (:meth:`Diagnosis.to_dict
  <lagsplat.diagnose.select.Diagnosis.to_dict>`: every candidate's fit with
  coefficients and standard errors, ``Delta BIC``, ``R2``, CV gain, the
  signatures), where the gap shows (:mod:`lagsplat.diagnose.where`), the
  held-out gap before and after the refit (:mod:`lagsplat.diagnose.refit`), the
  refit terms and the energy check, the settings and which frames were used
  for what;
* ``report.md``: the same for a reader;
* ``figures/where_{time,state,latent,image}.png`` and ``figures/gap.png``
  (held-out free rollouts before / after against the encoded video);
* ``refit.pt`` when a refit was made (:func:`lagsplat.diagnose.refit.load_refit`).

Frames: the diagnosis (residual, selection) and the localisation read the
*training* frames only (``diagnose.split``); the refit reads the training
frames (windows and model selection, as Stage 2); the held-out frames are
read only by the gap measurement.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from lagsplat import metrics, timeseries
from lagsplat.artifacts import DIAGNOSIS_FIGURES, DIAGNOSIS_FILES, Artifacts
from lagsplat.diagnose import diagnose_chart
from lagsplat.diagnose.gap import (
    common_noise_floor,
    energy_check,
    gap_reduction,
    held_out_gap,
)
from lagsplat.diagnose.localise import localise
from lagsplat.diagnose.markdown import GAP_LABELS, fmt_pct, render_markdown
from lagsplat.diagnose.refit import (
    GAP_METRICS,
    RefitConfig,
    add_control,
    choose_by_refit,
    refit,
    save_refit,
)
from lagsplat.diagnose.where import WhereConfig, split_code
from lagsplat.diagnose.where_plots import plot_where
from lagsplat.dynamics.integrators import actuation_schedule, initial_state, rollout
from lagsplat.io.atomic import atomic_write, write_json
from lagsplat.io.clip import HELD_OUT
from lagsplat.io.common import jsonable

__all__ = ["DiagnoseConfig", "diagnose_system", "diagnose_artifacts", "render_markdown", "write_report", "plot_gap", "reliability", "held_out_check"]



@dataclass
class DiagnoseConfig:
    """Settings of the ``diagnose`` stage (``conf/config.yaml``, group ``diagnose``).

    Attributes:
        split: frames the diagnosis and the localisation read (``"train"``; the
            held-out frames are kept for the gap).
        sigma: residual smoothing, frames (``None``: automatic).
        select: keyword arguments of :func:`lagsplat.diagnose.select_effect`
            (``min_delta_bic``, ``min_r2``, ``min_cv_gain``, ``max_effects``, ...).
        where: :class:`~lagsplat.diagnose.where.WhereConfig`.
        refit: :class:`~lagsplat.diagnose.refit.RefitConfig`.
    """

    split: str = "train"
    sigma: float | None = None
    select: dict[str, Any] = field(default_factory=dict)
    where: WhereConfig = field(default_factory=WhereConfig)
    refit: RefitConfig = field(default_factory=RefitConfig)

    @classmethod
    def from_mapping(cls, m: Mapping[str, Any] | None) -> DiagnoseConfig:
        """Build from a (Hydra) mapping.

        Raises:
            KeyError: on an unknown key (in any sub-group).
        """
        m = dict(m or {})
        unknown = set(m) - {"split", "sigma", "select", "where", "refit"}
        if unknown:
            raise KeyError(f"unknown diagnose settings: {sorted(unknown)}")
        return cls(
            split=str(m.get("split", "train")), sigma=None if m.get("sigma") is None else float(m["sigma"]),
            select=dict(m.get("select") or {}), where=WhereConfig.from_mapping(m.get("where")),
            refit=RefitConfig.from_mapping(m.get("refit")),
        )  # fmt: skip

    def to_dict(self) -> dict[str, Any]:
        """Plain record (saved in ``report.json``)."""
        return {"split": self.split, "sigma": self.sigma, "select": dict(self.select), "where": asdict(self.where), "refit": asdict(self.refit)}



# ---------------------------------------------------------------------- reliability
def reliability(chart: Any, stage2_history: Mapping[str, Any] | None = None, diagnosis: Any | None = None) -> dict[str, Any]:
    """Whether the upstream artifacts are good enough for the diagnosis to mean anything.

    A residual is only the sign of an unmodelled effect when the chart follows the
    object and the model follows the chart; otherwise any candidate may win (or
    none). Checks:

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

    The first two (Stage 1) make the verdict ``reliable``. The last two are
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
    jump = chart.meta.get("continuity_jump_ratio") if isinstance(chart.meta, Mapping) else None
    if jump is not None:
        checks["chart_continuous"] = {"ok": bool(jump < FOLD_WARNING), "value": float(jump), "threshold": FOLD_WARNING,
                                      "text": "chart jump ratio (max |2nd difference| / median |1st difference|)"}  # fmt: skip
    lam = float(np.linalg.eigvalsh(0.5 * (chart.G_bar + chart.G_bar.T)).max())
    floor = float(chart.ae_floor_train)
    if floor > 0:
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

    reasons = [why(k) for k in ("chart_continuous", "decoder_shows_motion") if k in checks and not checks[k]["ok"]]
    cautions = [why(k) for k in ("model_follows_training", "residual_explained") if k in checks and not checks[k]["ok"]]
    return {"reliable": not reasons, "checks": checks, "reasons": reasons, "cautions": cautions}


# ---------------------------------------------------------------------- gap figure
@torch.no_grad()
def plot_gap(chart: Any, runs: Mapping[str, tuple[Any, Any]], path: str | Path, title: str = "", sigma: float = 1.0) -> Path | None:
    """Figure: the longest held-out segment, encoded, with one free rollout per model (started past the smoothing edge, like the metrics).

    Args:
        chart: the chart (encoded trajectory).
        runs: ``{label: (model, chart_the_model_reads)}``.
        path: PNG written atomically.
        title: figure title.
        sigma: smoothing of the encoded trajectory, frames.

    Returns:
        ``path``, or ``None`` when the chart has no held-out segment of 4 frames.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    held = [s for s in chart.segments(HELD_OUT) if len(s) >= 4]
    if not held:
        return None
    ho = max(held, key=len)
    dt = float(np.median(np.diff(chart.t)))
    top = metrics.top_direction(chart.G_bar)
    q_s = timeseries.gaussian_smooth(chart.q[ho], sigma)
    fig, ax = plt.subplots(1, 1, figsize=(10, 3.6))
    ax.plot(chart.t[ho], q_s @ top, color="k", lw=1.6, label="encoded (held out)")
    a = metrics.rollout_start(sigma, len(ho), 3)  # past the smoothing's edge, as the metrics start
    for i, (label, (model, ch)) in enumerate(runs.items()):
        q0, v0 = initial_state(q_s, np.array([a]), dt)
        u = ch.u[ho[a:]]
        sim, _ = rollout(model, q0, v0, dt, len(ho) - a, u=actuation_schedule(u[None] if u.shape[1] else None, dt))
        ax.plot(chart.t[ho[a:]], sim[0].double().numpy() @ top, lw=1.1, color=f"C{i}", label=label, alpha=0.9)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("q on top G_bar direction")
    ax.legend(fontsize=8, loc="upper right")
    ax.set_title((title + ": " if title else "") + f"held-out gap, one free rollout from held-out frame {a}", fontsize=9)
    path = Path(path)
    with atomic_write(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path


# ---------------------------------------------------------------------- the analysis
def diagnose_artifacts(
    clip: Any | None, ae: Any | None, chart: Any, model: Any, stage2_cfg: Any | None, out_dir: str | Path,
    cfg: DiagnoseConfig | None = None, eval_cfg: Any | None = None, title: str = "", system: str = "", inertia: Any | None = None,
    metrics_json: Mapping[str, Any] | None = None, progress: bool = False, stage2_history: Mapping[str, Any] | None = None,
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

    Returns:
        The report (the content of ``report.json``).
    """
    from lagsplat.evaluate import EvalConfig

    cfg = cfg or DiagnoseConfig()
    eval_cfg = eval_cfg or EvalConfig()
    out = Path(out_dir)
    fig_dir = out / "figures"
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    which = split_code(cfg.split)
    diag, res = diagnose_chart(model, chart, which, cfg.sigma, **cfg.select)
    timings["diagnosis_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    where = localise(model, chart, res, None if clip is None else clip.images, ae, cfg.where, which)
    figures = {k: str(Path(v).relative_to(out)) for k, v in plot_where(where, fig_dir, title or system).items()}
    timings["where_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    source = f"{system or 'system'} held-out frames"
    before = held_out_gap(chart, model, clip, ae, eval_cfg, source)
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
    refit_rec: dict[str, Any] = {"done": False}
    runs = {"identified model (before)": (model, chart)}
    if diag.winner == "none":
        refit_rec["reason"] = "nothing significant: no refit"
    elif not cfg.refit.enabled:
        refit_rec["reason"] = "refit disabled (diagnose.refit.enabled=false)"
    elif stage2_cfg is None:
        refit_rec["reason"] = "no Stage-2 settings given: no refit"
    else:
        chosen = None
        if cfg.refit.choose:
            t1 = time.perf_counter()
            base = (stage2_history or {}).get("selected_nrmse")
            base = None if base is None else float(base)
            diag, choice, chosen = choose_by_refit(chart, model, stage2_cfg, diag, base, cfg.refit, inertia)
            refit_rec["baseline_train_rollout_nrmse"] = base
            if choice:
                refit_rec["choice"] = choice
                timings["choice_s"] = time.perf_counter() - t1
        if chosen is not None:  # the chosen effect's refit is made: only its control is left to run
            r = add_control(chosen, chart, model, stage2_cfg, cfg.refit, inertia, progress) if cfg.refit.control else chosen
        else:
            r = refit(chart, model, stage2_cfg, diag, cfg.refit, inertia, progress)
        if r is None:
            from lagsplat.diagnose.refit import refit_spec

            sp = refit_spec(diag, model, cfg.refit.init)
            refit_rec.update(reason="no Stage-2 remedy for the effect(s) found", spec=sp.to_dict())
        else:
            after = held_out_gap(r.chart, r.model, clip, ae, eval_cfg, source)
            ctrl = None if r.control is None else held_out_gap(chart, r.control, clip, ae, eval_cfg, source)
            before, after, ctrl = common_noise_floor(before, after, ctrl)  # compared over one chart-noise floor
            gap.update(before=before, after=after, reduction=gap_reduction(before, after))
            runs[f"refit with {', '.join(r.spec.effects)} (after)"] = (r.model, r.chart)
            if ctrl is not None:
                gap["control"] = ctrl
                gap["reduction_vs_control"] = gap_reduction(ctrl, after)
                runs["same fine-tune without the term (control)"] = (r.control, chart)
            gap["held_out_check"] = held_out_check(gap, r.spec.effects)
            refit_rec.update(
                done=True, spec=r.spec.to_dict(), fitted_terms=r.fitted_terms, energy_check=energy_check(r.model, r.chart),
                selected_epoch=r.history.get("selected_epoch"), selected_train_nrmse=r.history.get("selected_nrmse"),
                control_selected_train_nrmse=None if r.control_history is None else r.control_history.get("selected_nrmse"),
                checkpoint=DIAGNOSIS_FILES["refit"],
            )  # fmt: skip
            save_refit(out / DIAGNOSIS_FILES["refit"], r, stage2_cfg)
    if not refit_rec["done"] and (out / DIAGNOSIS_FILES["refit"]).exists():  # a refit of an earlier run no longer applies
        (out / DIAGNOSIS_FILES["refit"]).unlink()
    p = plot_gap(chart, runs, fig_dir / DIAGNOSIS_FIGURES["gap"], title or system, eval_cfg.sigma)
    if p is not None:
        figures["gap"] = str(Path(p).relative_to(out))
    for fname in DIAGNOSIS_FIGURES.values():  # figures of an earlier run that no longer apply
        f = fig_dir / fname
        if f.exists() and f"figures/{fname}" not in figures.values():
            f.unlink()
    timings["gap_and_refit_s"] = time.perf_counter() - t0

    n_which = sum(len(s) for s in (chart.segments(which) if which is not None else [np.arange(len(chart.t))]))
    report = {
        "system": system, "title": title, "verdict": diag.winner,
        "verdict_text": "nothing significant" if diag.winner == "none" else ", ".join(diag.labels),
        "reliability": reliability(chart, stage2_history, diag),
        "summary": diag.summary(),
        "diagnosis": diag.to_dict(),
        "where": where.summary(),
        "gap": gap,
        "refit": refit_rec,
        "figures": figures,
        "frames": {
            "diagnosis_split": cfg.split, "n_diagnosis_frames": int(n_which),
            "n_held_out_frames": int(np.sum(np.asarray(chart.split) == HELD_OUT)),
            "held_out_used_for": "the gap only (before / after / control)",
        },
        "config": cfg.to_dict(),
        "timings": timings,
    }  # fmt: skip
    report = jsonable(report)
    write_report(report, out)
    return report


def diagnose_system(
    artifacts: Artifacts | str | Path, cfg: DiagnoseConfig | None = None, eval_cfg: Any | None = None, title: str = "", progress: bool = False,
) -> dict[str, Any]:
    """:func:`diagnose_artifacts` on the artifacts of one run.

    Args:
        artifacts: the run's :class:`~lagsplat.artifacts.Artifacts` (``clip.npz``, ``stage1.pt``,
            ``chart.npz``, ``stage2.pt``, optional ``metrics.json``; the report goes to
            ``artifacts.diagnosis``), or a ``results/<system>/`` folder in the standard layout.
        cfg, eval_cfg, title, progress: see :func:`diagnose_artifacts`.

    Returns:
        The report.

    Raises:
        FileNotFoundError: naming the first missing artifact.
    """
    from lagsplat.train.stage2 import Stage2Config

    a = artifacts if isinstance(artifacts, Artifacts) else Artifacts.at(artifacts)
    a.require("clip", "stage1", "chart", "stage2")
    clip, ae, chart = a.load_clip(), a.load_stage1(), a.load_chart()
    model, ck = a.load_stage2()
    s2 = Stage2Config.from_mapping(ck["config"])
    inertia = None
    if s2.mass == "decoder":
        from lagsplat.models.lagrangian import DecoderInertia

        inertia = DecoderInertia.from_decoder(ae.decoder, chart.W_inv, chart.mean, chart.height, chart.width)
    mj = a.load_metrics()
    name = a.system_dir.name
    return diagnose_artifacts(
        clip, ae, chart, model, s2, a.diagnosis, cfg, eval_cfg,
        title or (mj or {}).get("title", name), name, inertia, mj, progress, ck.get("history"),
    )  # fmt: skip


# ---------------------------------------------------------------------- markdown
#: Gap metrics the held-out check reads (the trajectory and the image; frequency and envelope are reported beside).
CHECK_METRICS = ("eps_q", "image_excess")


def held_out_check(gap: Mapping[str, Any], effects: Sequence[str]) -> dict[str, Any] | None:
    """Whether the refit with the diagnosed effect(s) shrinks the held-out gap: a statement, never a choice.

    Confirmed when, for each of :data:`CHECK_METRICS`, the refit model's held-out gap is
    below the identified model's and below the control fine-tune's (same settings, no term),
    so that what the term buys is not what more training buys. The held-out frames
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
    ok = all(v > 0 for v in vals)
    name = ", ".join(effects)
    nums = "; ".join(
        f"{k.replace('_', ' ')} {fmt_pct(red[k])}" + (f" (vs the control fine-tune {fmt_pct(red_c[k])})" if gap.get("control") else "")
        for k in CHECK_METRICS
    )
    text = (
        f"the refit with {name} shrinks the held-out gap ({nums})" if ok
        else f"the refit with {name} does not shrink the held-out gap beyond more training ({nums}): "
        "what the training frames point to is not confirmed on the held-out frames"
    )
    return {"confirmed": bool(ok), "text": text}


def write_report(report: Mapping[str, Any], out_dir: str | Path) -> tuple[Path, Path]:
    """Write ``report.json`` and ``report.md`` under ``out_dir`` atomically; returns their paths."""
    out = Path(out_dir)
    pj = write_json(out / DIAGNOSIS_FILES["report_json"], report)
    pm = out / DIAGNOSIS_FILES["report_md"]
    with atomic_write(pm) as tmp:
        tmp.write_text(render_markdown(report))
    return pm, pj
