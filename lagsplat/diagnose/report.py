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

from lagsplat.artifacts import DIAGNOSIS_FIGURES, DIAGNOSIS_FILES, Artifacts
from lagsplat import metrics, timeseries
from lagsplat.diagnose import diagnose_chart
from lagsplat.diagnose.select import plain_value
from lagsplat.diagnose.refit import (
    GAP_METRICS,
    RefitConfig,
    add_control,
    choose_by_refit,
    common_noise_floor,
    energy_check,
    gap_reduction,
    held_out_gap,
    refit,
    save_refit,
)
from lagsplat.diagnose.where import WhereConfig, localise, plot_where, split_code
from lagsplat.dynamics.integrators import actuation_schedule, initial_state, rollout
from lagsplat.io.atomic import atomic_write, write_json
from lagsplat.io.clip import HELD_OUT

__all__ = ["DiagnoseConfig", "diagnose_system", "diagnose_artifacts", "render_markdown", "write_report", "plot_gap", "reliability", "held_out_check"]

_GAP_LABELS = {
    "eps_q": "eps_q (latent NRMSE, 2 periods)",
    "eps_freq": "eps_freq (free-oscillation frequency error)",
    "envelope_decay_error": "envelope-decay error",
    "image_excess": "image error over the AE floor, (eps_I - eps_AE) / eps_AE",
    "eps_q_over_floor": "eps_q over the chart-noise floor, eps_q - eps_q_floor (what a model with no gap scores on this chart; lowest of the models compared)",
    "eps_freq_over_floor": "eps_freq over the chart-noise floor, eps_freq - eps_freq_floor (likewise)",
}


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
        "definition": {k: _GAP_LABELS[k] for k in GAP_METRICS} | {
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
    report = plain_value(report)
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
def _f(x: Any, fmt: str = ".3g") -> str:
    if x is None:
        return "n/a"
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, (int, float)):
        return format(x, fmt) if math.isfinite(x) else "n/a"
    return str(x)


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
        f"{k.replace('_', ' ')} {_pct(red[k])}" + (f" (vs the control fine-tune {_pct(red_c[k])})" if gap.get("control") else "")
        for k in CHECK_METRICS
    )
    text = (
        f"the refit with {name} shrinks the held-out gap ({nums})" if ok
        else f"the refit with {name} does not shrink the held-out gap beyond more training ({nums}): "
        "what the training frames point to is not confirmed on the held-out frames"
    )
    return {"confirmed": bool(ok), "text": text}


def _pct(x: Any) -> str:
    return "n/a" if x is None else f"{100 * x:+.0f} %"


def render_markdown(rep: Mapping[str, Any]) -> str:
    """``report.md`` from the report mapping (the content of ``report.json``)."""
    dg = rep["diagnosis"]
    L: list[str] = [f"# Sim-to-real gap diagnosis: {rep.get('title') or rep.get('system')}", ""]
    verdict = rep["verdict_text"]
    L += [f"**Verdict: {verdict}.**", ""]
    rel = rep.get("reliability")
    if rel and not rel["reliable"]:
        L += ["**Unreliable**: the chart does not support a diagnosis (" + "; ".join(rel["reasons"]) + "). "
              "Improve Stage 1 first; the verdict below is what the residual says, not a finding.", ""]  # fmt: skip
    if rel and rel.get("cautions"):
        L += ["Caution: " + "; ".join(rel["cautions"]) + ". The identified model misses much of the training motion: a strong "
              "unmodelled effect, a Stage-2 failure or a distorted chart (the evidence below cannot tell these apart "
              "unless a candidate explains the residual).", ""]  # fmt: skip
    null = dg["null"]
    if rep["verdict"] == "none":
        L.append(
            "No candidate effect explains the residual of the identified model significantly beyond the model-class "
            "corrections (rule: physical, Delta BIC >= {min_delta_bic:g}, R2 >= {min_r2:g}, blocked-CV gain >= {min_cv_gain:g}).".format(**dg["settings"])
        )
    else:
        for e in dg["effects"]:
            it = e.get("interpretation", {})
            L.append(f"- **{e['effect']}**: {it.get('text', '')}")
    L.append(f"- residual after the model-class corrections: {_f(null.get('excess_after_effects', null['excess_over_noise']))} x the chart-noise variance "
             f"(null fit: {_f(null['excess_over_noise'])}).")  # fmt: skip
    if null.get("warning"):
        L.append(f"- warning: {null['warning']}")
    choice = (rep.get("refit") or {}).get("choice")
    if choice:
        rows = ", ".join(f"{c['effect']} {_f(c['train_rollout_nrmse'], '.3f')}" for c in choice)
        won, first = next(c for c in choice if c["chosen"]), choice[0]
        base = rep["refit"].get("baseline_train_rollout_nrmse")
        if won is not first:
            how = f"is not confirmed (its refit follows the training video worse than the identified model), {won['effect']} is taken instead"
        elif first["beats_identified"]:
            how = "is confirmed"
        else:
            how = "stands (no candidate's refit follows the training video better than the identified model)"
        L.append(f"- several candidates are significant; the Delta-BIC winner {first['effect']} {how}, by the training-rollout NRMSE "
                 f"of the model refit with {'it' if len(choice) == 1 else 'each'} (paper §3.3; identified model {_f(base, '.3f')}): {rows}.")  # fmt: skip
    check = (rep.get("gap") or {}).get("held_out_check")
    if check:
        L.append(f"- held-out check: {check['text']}.")
    st = dg["settings"]
    smooth = ""
    if st.get("sigma_frames_out_of_class") is not None:  # the two regressions' smoothing (lagsplat.diagnose.select, "Band of the out-of-class regression")
        smooth = (f"; in-class candidates (end stop, cubic stiffness) on the residual smoothed over {_f(st['sigma_frames'], '.2f')} frames, "
                  f"the other candidates over {_f(st['sigma_frames_out_of_class'], '.2f')}")  # fmt: skip
    L += ["", "## Evidence", "", f"Ranking (first round; Delta BIC against the nuisance-only fit, higher is better{smooth}):", "",
          "| effect | Delta BIC | R2 | CV gain | physical | significant | coefficients (value +- s.e.) |", "|---|---|---|---|---|---|---|"]  # fmt: skip
    for c in dg["ranking"]:
        coefs = "; ".join(f"{n} = {_f(v['value'])} +- {_f(v['se'], '.2g')}" for n, v in c["coefficients"].items())
        L.append(f"| {c['effect']} | {_f(c['delta_bic'], '.1f')} | {_f(c['r2'], '.2f')} | {_f(c['cv_gain'], '.2f')} | {_f(c['physical'])} | {_f(c['significant'])} | {coefs} |")
    if len(dg["ranking"]) > 1:
        a, b = dg["ranking"][0], dg["ranking"][1]
        L += ["", f"Margin of the first over the second: Delta BIC {_f(a['delta_bic'] - b['delta_bic'], '.1f')}, CV gain {_f(a['cv_gain'] - b['cv_gain'], '.2f')}."]
    ev = dg["evidence"]
    L += ["", "Signatures (most visible latent direction):", ""]
    env = ev.get("envelope", {})
    if env.get("best"):
        ratios = ", ".join(f"{k} {_f(v, '.2f')}" for k, v in (env.get("sse_ratio_to_best") or {}).items())
        L.append(f"- envelope of the decay: best **{env['best']}** ({env['n_turning_points']} turning points; SSE / best: {ratios})")
    fr = ev.get("frequency", {})
    if "slope_amp2" in fr:
        L.append(f"- frequency vs amplitude^2: z = {_f(fr['z_amp2'], '.1f')} (shift at the largest amplitude {_pct(fr['relative_shift_at_max_amplitude'])}); "
                 f"vs time: z = {_f(fr['z_time'], '.1f')} (change over the span {_pct(fr['relative_change_over_span'])})")  # fmt: skip
    sp = ev.get("spectrum", {})
    if sp:
        L.append(f"- residual spectral peaks (Hz): {', '.join(_f(f) for f in sp.get('residual_peaks_hz', [])) or 'none'}; "
                 f"not explained by the model's modes: {', '.join(_f(f) for f in sp.get('unexplained_peaks_hz', [])) or 'none'}")  # fmt: skip
    asy = ev.get("asymmetry")
    if asy:
        L.append(f"- excursion asymmetry: {_f(asy['ratio'], '.2f')} (1 = symmetric)")

    w = rep["where"]
    L += ["", "## Where it shows", ""]
    tl = w.get("time")
    if tl:
        L.append(f"**Time** ({_f(tl['duration_s'], '.1f')} s of {rep['frames']['diagnosis_split']} frames, {tl['rollout_horizon_frames']}-frame free rollouts): "
                 f"rollout error above {rep['config']['where']['floor_factor']:g}x the AE floor on {_pct(tl['share_flagged_rollout'])[1:]} of the frames, "
                 f"one-step residual above {rep['config']['where']['floor_factor']:g}x the chart noise on {_pct(tl['share_flagged_residual'])[1:]}, both on {_pct(tl['share_flagged_both'])[1:]}; "
                 f"median rollout error / floor {_f(tl['median_rollout_over_floor'], '.2f')}, median residual z^2 {_f(tl['median_residual_z2'], '.2f')}.")  # fmt: skip
        if tl["windows"]:
            L += ["", "| window (s) | frames | peak rollout error / floor | mean residual z^2 |", "|---|---|---|---|"]
            for win in tl["windows"][:8]:
                L.append(f"| {win['t_start_s']:.2f} - {win['t_end_s']:.2f} | {win['n_frames']} | {_f(win['peak_rollout_over_floor'], '.1f')} | {_f(win['mean_residual_z2'], '.1f')} |")
            if len(tl["windows"]) > 8:
                L.append(f"| ... {len(tl['windows']) - 8} more | | | |")
        else:
            L.append("No window where both exceed their floor.")
    st = w.get("state")
    if st:
        L += ["", f"**State** (phase portrait; most enriched: **{st['most_enriched'].replace('_', ' ')}**):", "",
              "| region | share of samples | share of residual | enrichment | mean z^2 |", "|---|---|---|---|---|"]  # fmt: skip
        for name, r in st["regions"].items():
            L.append(f"| {name.replace('_', ' ')} | {_f(r['sample_share'], '.2f')} | {_f(r['residual_share'], '.2f')} | {_f(r['enrichment'], '.2f')} | {_f(r['mean_z2'], '.2f')} |")
    lt = w.get("latent")
    if lt:
        L += ["", "**Latent directions** (eigenvectors of G_bar, most visible first):", "",
              "| direction | eigenvalue | visibility share | residual share | residual share (G_bar-weighted) | residual / noise | rollout-gap share (G_bar-weighted) |",
              "|---|---|---|---|---|---|---|"]  # fmt: skip
        for k, r in enumerate(lt["directions"]):
            L.append(f"| e{k + 1} | {_f(r['eigenvalue'])} | {_f(r['visibility_share'], '.2f')} | {_f(r['residual_share'], '.2f')} | "
                     f"{_f(r['residual_share_G'], '.2f')} | {_f(r['residual_over_noise'], '.2f')} | {_f(r['rollout_share_G'], '.2f')} |")  # fmt: skip
    im = w.get("image")
    if im:
        L += ["", f"**Image** ({im['n_frames']} rendered rollout frames): rollout image error {_f(im['eps_rollout'])} against the AE floor "
              f"{_f(im['eps_ae'])} on the same frames (excess {_pct(im['excess_over_ae'])}). The positive excess falls "
              f"{_pct(im['share_moving_gaussians'])[1:]} on moving Gaussians ({im['n_moving']} of {im['n_gaussians']}; they carry "
              f"{_pct(im['moving_coverage'])[1:]} of the rendered colour, enrichment {_f(im['moving_enrichment'], '.1f')}x), "
              f"{_pct(im['share_static_gaussians'])[1:]} on static ones and {_pct(im['share_background'])[1:]} on the background; "
              f"hottest pixel (x, y) = {tuple(im['hottest_pixel_xy'])}.", "",
              "| Gaussian | share | position (px) | motion (px per unit q) |", "|---|---|---|---|"]  # fmt: skip
        for g in im["top_gaussians"][:8]:
            L.append(f"| #{g['index']} | {_f(g['share'], '.3f')} | ({g['position_px'][0]:.1f}, {g['position_px'][1]:.1f}) | {_f(g['motion_px'], '.2f')} |")
    for n in w.get("notes", []):
        L.append(f"- note: {n}")

    gap = rep["gap"]
    fr_def = gap["definition"]["frames"]
    L += ["", "## Held-out gap", "", fr_def[:1].upper() + fr_def[1:] + ".", ""]
    cols = ["before"] + (["after"] if gap["after"] else []) + (["control"] if gap["control"] else [])
    head = {"before": "before (identified model)", "after": "after (refit with the effect)", "control": "control (same refit, no term)"}
    L += ["| metric | " + " | ".join(head[c] for c in cols) + (" | reduction | reduction vs control |" if gap["after"] else " |"),
          "|---" * (len(cols) + 1 + (2 if gap["after"] else 0)) + "|"]  # fmt: skip
    for k in GAP_METRICS:
        row = f"| {_GAP_LABELS[k]} | " + " | ".join(_f(gap[c].get(k), ".4g") for c in cols)
        if gap["after"]:
            row += f" | {_pct(gap['reduction'].get(k))} | {_pct((gap['reduction_vs_control'] or {}).get(k))}"
        L.append(row + " |")
    env_b = gap["before"].get("envelope") or {}
    if env_b.get("form"):
        L.append(f"\nEnvelope: {env_b['form']} fit; the encoded held-out video loses {_pct(env_b['decay_encoded'])[1:]} of its amplitude over the segment"
                 + ("" if env_b.get("reliable") else " (too little decay for a reliable relative error)") + ".")  # fmt: skip
    fl = gap["before"].get("floor") or {}
    if fl.get("eps_q") is not None:
        L.append(f"\nChart-noise floor (lagsplat.diagnose.refit.noise_floor: the identified model's own motion plus the chart's noise, "
                 f"{fl['n_draws']} draws): eps_q {_f(fl['eps_q'], '.4g')} ± {_f(fl['eps_q_sd'], '.2g')}, eps_freq {_f(fl['eps_freq'], '.3g')}; "
                 "what no model can remove from this chart.")  # fmt: skip
    if "before_matches_metrics_json" in gap:
        L.append(f"\nThe 'before' eps_q {'matches' if gap['before_matches_metrics_json'] else 'differs from'} metrics.json ({_f(gap['metrics_json_eps_q'], '.4g')}).")
    rf = rep["refit"]
    L += ["", "## Refit", ""]
    if not rf.get("done"):
        L.append(rf.get("reason", "no refit"))
        for k, v in (rf.get("spec", {}) or {}).get("not_refit", {}).items():
            L.append(f"- {k}: {v}")
    else:
        cfg = rep["config"]["refit"]
        L.append(f"Stage 2 refit ({cfg['init']} start, {cfg['epochs']} epochs, energy gauge x{cfg['floor_scale']:g}; model selection on training rollouts), "
                 f"selected epoch {rf['selected_epoch']}, training-rollout NRMSE {_f(rf['selected_train_nrmse'], '.4g')} (control {_f(rf['control_selected_train_nrmse'], '.4g')}).")  # fmt: skip
        for t0, t1 in zip(rf["spec"]["init_terms"], rf["fitted_terms"]):
            vals = ", ".join(f"{k} {_f(t0[k])} -> {_f(t1[k])}" for k in t1 if k not in ("class", "direction") and isinstance(t1[k], (int, float)))
            L.append(f"- {t1['class']} along {[round(v, 3) for v in t1['direction']]}: {vals} (start -> refit)")
        if rf["spec"]["delay_s"]:
            L.append(f"- input read {rf['spec']['delay_s']:.3f} s late")
        for k, v in rf["spec"].get("not_refit", {}).items():
            L.append(f"- {k} not refit: {v}")
        ec = rf["energy_check"]
        L.append(f"- energy bound (App. A.2): {'holds' if ec['holds'] else 'VIOLATED'}; max power of the dissipative terms "
                 f"{_f(ec['max_dissipative_power'], '.2g')}, max energy rise along free rollouts {_f(ec['max_energy_rise'], '.2g')}")  # fmt: skip
    if rep.get("figures"):
        L += ["", "## Figures", ""] + [f"- {k}: [{v}]({v})" for k, v in rep["figures"].items()]
    fr_ = rep["frames"]
    L += ["", f"Frames: diagnosis and localisation on {fr_['n_diagnosis_frames']} {fr_['diagnosis_split']} frames; "
          f"{fr_['n_held_out_frames']} held-out frames used for {fr_['held_out_used_for']}.", ""]  # fmt: skip
    return "\n".join(L)


def write_report(report: Mapping[str, Any], out_dir: str | Path) -> tuple[Path, Path]:
    """Write ``report.json`` and ``report.md`` under ``out_dir`` atomically; returns their paths."""
    out = Path(out_dir)
    pj = write_json(out / DIAGNOSIS_FILES["report_json"], report)
    pm = out / DIAGNOSIS_FILES["report_md"]
    with atomic_write(pm) as tmp:
        tmp.write_text(render_markdown(report))
    return pm, pj
