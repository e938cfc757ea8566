"""Blind check of the sim-to-real gap diagnosis at the image level.

Every clip of the blind suite (:func:`lagsplat.synth.effect_clips.blind_suite`: a
pendulum and a cart, each candidate effect ``--n-per-effect`` times, controls
and actuated controls included) is rendered and run through the whole
pipeline, as ``python -m lagsplat all`` + ``diagnose`` would on a video:

    ingest -> Stage 1 -> chart -> Stage 2 -> evaluate -> diagnose (+ refit, held-out gap)

Blind: the clip saved for the pipeline (``clip.npz``) carries no label, truth
or latent (its ``meta`` keeps only the source and the rendering parameters);
the label goes to ``label.json`` beside it, read only by the scorer. The
latent dimension is 1 for every clip (a user would pick 1 for a single swinging
or sliding object); a missing degree of freedom must be found from the
residual.

Artifacts are cached per clip under ``--results/<budget>/<clip>/`` (the layout
of ``results/<system>/``), so an interrupted run resumes where it stopped;
``--force`` recomputes everything, ``--rediagnose`` only the diagnosis (and
the held-out gap of the ``d = 2`` remedy).
``--budget`` trades fidelity for time:

========== ========= ========= ============ ============== ============== ================
budget     size (px) Gaussians Stage-1 steps chart refine   Stage-2 epochs refit epochs
========== ========= ========= ============ ============== ============== ================
cheap      32 x 32   256       800 (*)      8 (***)        200 (**)       150 (****)
standard   64 x 64   512       1500         8 (***)        100            100
full       64 x 64   1024      3000         0              100            100
========== ========= ========= ============ ============== ============== ================

(``full`` is the settings of ``conf/config.yaml``; (*) with ``sigma_xy = 0.05``: at
32 px the configured 0.03 leaves 256 Gaussians too small to cover the frame
and Stage 1 fails within 800 steps; (**) on these 32 px charts Stage 2 is
still converging at 60 epochs, and what it has not fitted hides the effect:
on ``pendulum-quadratic_drag-0`` the model's held-out frequency is 1.9 % off
after 60 epochs (selected epoch 49), 0.30 % after 200 (about 30 s on one core);
(***) ``chart.refine_iters`` (:func:`lagsplat.chart.refine_latents`, about 15 s
per clip at 32 px): an encoder trained for 800 steps reads the turning points
short (up to 0.3 in whitened units on ``cart-coulomb-0``), which Stage 2 fits as
physics and no candidate term explains; ``--refine-iters 0`` gives the
encoder's chart; (****) a 60-epoch fine-tune stopped while the refit was still
improving on its training rollouts (selected epoch 59 on ``cart-end_stop-1``,
left under-damped: damping ratio 0.006 against the clip's 0.008); with 150 the
suite's median reductions went from +54, +30, +68, +69 % to +51, +46, +76,
+70 % (``eps_q``, ``eps_freq``, envelope, image), ``--refit-epochs`` sets
another value.) Prints one row per clip,
the confusion matrix (rows: truth, columns: verdict), the top-1 accuracy
(controls count as correct when the verdict is "none"), the number of
controls flagged, and the median held-out gap reduction (``1 - after /
before``) per gap metric over the effect clips that were refit, with the
per-clip wall time of each stage. A missing degree of freedom has no Stage-2
term; with ``--dof-refit`` its remedy (Stage 1 to Stage 2 again with ``d = 2``,
under ``<clip>/d2/``) is scored instead (no control then).

    python benchmarks/diagnosis.py [--budget cheap] [--only pendulum-coulomb-0,cart-none-0]
                                   [--n-per-effect 2] [--results results/diagnosis_bench] [--json out.json]
                                   [--markdown out.md] [--list] [--force] [--rediagnose] [--dof-refit]
                                   [--refine-iters N] [--refit-epochs N]

A run over the whole suite, or ``--gather``, writes the summary with the
command line and the environment to ``results/benchmarks/diagnosis_<budget>.md``
(``--markdown PATH`` / ``--report PATH`` elsewhere, ``--no-report``: none); a
subset (``--only``, ``--clip``) writes one only when given a path.

One job per clip (what the Snakemake rules of ``workflow/rules/suite.smk`` run,
each clip on its own core or cluster node), then the scoring over all of them:

    python benchmarks/diagnosis.py --clip pendulum-coulomb-0 --row rows/pendulum-coulomb-0.json [--budget ...]
    python benchmarks/diagnosis.py --gather rows/*.json --markdown summary.md [--json summary.json]

``--clip`` runs exactly one clip of the suite (the same cache under
``--results``) and ``--row`` writes its scored row and stage timings as JSON;
``--gather`` reads such files (one budget) and prints and writes the same
summary as a run over the whole suite, without running anything.

Scores, not tests: nothing is asserted.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import asdict
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import lagsplat  # noqa: F401  (sets the OpenMP wait policy before torch)
import numpy as np
import torch
from _common import REPORTS, Report, commit_counts, git_commit, score_verdicts
from _common import measurable_gap_medians as measurable_gap_medians_of

from lagsplat.artifacts import Artifacts  # noqa: E402
from lagsplat.chart import build_chart, load_chart, save_chart
from lagsplat.chart.gate import chart_gate
from lagsplat.diagnose.refit import GAP_METRICS, RefitConfig
from lagsplat.diagnose.report import DiagnoseConfig, diagnose_system
from lagsplat.diagnose.where import WhereConfig
from lagsplat.evaluate import EvalConfig, evaluate
from lagsplat.io.atomic import write_json
from lagsplat.io.clip import Clip, load_clip, save_clip
from lagsplat.synth.effect_clips import blind_suite, make_effect_clip
from lagsplat.train.stage1 import Stage1Config, train_stage1
from lagsplat.models.autoencoder import load_stage1, save_stage1
from lagsplat.train.stage2 import Stage2Config, load_stage2, save_stage2, train_stage2

#: Budget name -> settings (see the module docstring).
BUDGETS = {
    "cheap": {"size": 32, "stage1": {"n_gaussians": 256, "steps": 800, "sigma_xy": 0.05, "recycle_warmup": 250, "recycle_every": 125}, "n_metric_samples": 16,
              "refine_iters": 8, "stage2": {"epochs": 200}, "refit_epochs": 150, "n_image_frames": 16},
    "standard": {"size": 64, "stage1": {"n_gaussians": 512, "steps": 1500, "sigma_xy": 0.05}, "n_metric_samples": 32, "refine_iters": 8, "stage2": {"epochs": 100},
                 "refit_epochs": 100, "n_image_frames": 32},
    "full": {"size": 64, "stage1": {"sigma_xy": 0.05}, "n_metric_samples": 64, "refine_iters": 0, "stage2": {"epochs": 100}, "refit_epochs": 100, "n_image_frames": 48},
}  # fmt: skip

#: Keys of ``clip.meta`` the pipeline may see (everything else, label and truth included, is withheld).
BLIND_META = ("source", "params")


def _stage1_defaults() -> dict:
    """The Stage-1 settings of ``conf/config.yaml`` (the pipeline's defaults)."""
    import yaml

    conf = yaml.safe_load((Path(__file__).resolve().parents[1] / "conf" / "config.yaml").read_text())
    return dict(conf["stage1"])


def blind_clip(entry: dict, size: int) -> tuple[Clip, dict]:
    """``(clip without label, label record)`` of one suite entry."""
    clip = make_effect_clip(entry["system"], entry["effect"], entry["seed"], entry["actuated"], size=(size, size))
    label = {"label": clip.meta["label"], "system": clip.meta["system"], "truth": clip.meta["truth"], "entry": entry}
    params = dict(clip.meta["params"])
    params.pop("effect", None)  # the generator's arguments name the effect: withheld too
    meta = {"source": "blind benchmark clip (lagsplat.synth.effects; label withheld)", "params": params}
    return Clip(images=clip.images, t=clip.t, u=clip.u, u_names=clip.u_names, split=clip.split, meta=meta, episode=clip.episode), label


def run_clip(entry: dict, budget: str, root: Path, seed: int, force: bool, dof_refit: bool = False, rediagnose: bool = False) -> dict:
    """Run (or resume) the pipeline and the diagnosis on one clip; returns the timing record."""
    b = BUDGETS[budget]
    d = root / budget / entry["name"]
    d.mkdir(parents=True, exist_ok=True)
    tpath = d / "timing.json"
    timing = json.loads(tpath.read_text()) if tpath.exists() and not force else {}

    def stage(name: str, path: Path, fn) -> None:
        if path.exists() and not (force or (rediagnose and name in ("diagnose", "dof_gap"))):
            return
        t0 = time.perf_counter()
        fn()
        timing[name] = round(time.perf_counter() - t0, 1)
        write_json(tpath, timing)

    a = Artifacts.at(d)

    def make_clip() -> None:
        clip, label = blind_clip(entry, b["size"])
        write_json(d / "label.json", label)
        save_clip(a.clip, clip)

    stage("clip", a.clip, make_clip)
    s1 = Stage1Config.from_mapping({**_stage1_defaults(), **b["stage1"]})
    s2 = Stage2Config.from_mapping(b["stage2"])

    def do_stage1() -> None:
        ae, hist = train_stage1(load_clip(a.clip), s1, 1, seed=seed, progress=False)
        save_stage1(a.stage1, ae, asdict(s1), hist, 1)

    def do_chart() -> None:  # with the chart-quality gate's result, recorded, not acted on (the suite scores the diagnosis)
        ae, clip = load_stage1(a.stage1), load_clip(a.clip)
        chart = build_chart(ae, clip, b["n_metric_samples"], 0.01, seed, b["refine_iters"])
        chart.meta["gate"] = chart_gate(ae, clip, chart)
        save_chart(a.chart, chart)

    def do_stage2() -> None:
        model, hist = train_stage2(load_chart(a.chart), s2, seed=seed, progress=False)
        save_stage2(a.stage2, model, s2, hist)

    def do_evaluate() -> None:
        clip, chart = load_clip(a.clip), load_chart(a.chart)
        model, ck = load_stage2(a.stage2)
        m = evaluate(clip, load_stage1(a.stage1), chart, model, EvalConfig(), source=str(a.clip))
        write_json(a.metrics, {"system": entry["name"], "title": entry["name"], "metrics": m, "stage2": asdict(s2),
                                        "stage2_selected_epoch": ck["history"].get("selected_epoch")})  # fmt: skip

    def do_diagnose() -> None:
        cfg = DiagnoseConfig(where=WhereConfig(n_image_frames=b["n_image_frames"]), refit=RefitConfig(epochs=b["refit_epochs"], seed=seed))
        diagnose_system(a, cfg=cfg, eval_cfg=EvalConfig(), title=entry["name"])

    stage("stage1", a.stage1, do_stage1)
    stage("chart", a.chart, do_chart)
    stage("stage2", a.stage2, do_stage2)
    stage("evaluate", a.metrics, do_evaluate)
    stage("diagnose", a.report_json, do_diagnose)
    if dof_refit and json.loads((a.report_json).read_text())["verdict"] == "missing_dof":
        stage("dof_refit", Artifacts.at(d / "d2").stage2, lambda: refit_missing_dof(d, s1, s2, b, seed))
        stage("dof_gap", d / "d2" / "gap.json", lambda: score_missing_dof(d))  # --rediagnose scores it again
    return timing


def refit_missing_dof(d: Path, s1: Stage1Config, s2: Stage2Config, b: dict, seed: int) -> None:
    """The remedy of a missing degree of freedom: Stage 1, chart and Stage 2 again with ``d = 2``, under ``<clip>/d2/``."""
    a, a2 = Artifacts.at(d), Artifacts.at(d / "d2")
    clip = load_clip(a.clip)
    ae, hist = train_stage1(clip, s1, 2, seed=seed, progress=False)
    save_stage1(a2.stage1, ae, asdict(s1), hist, 2)
    chart = build_chart(ae, clip, b["n_metric_samples"], 0.01, seed, b["refine_iters"])
    save_chart(a2.chart, chart)
    model, h2 = train_stage2(chart, s2, seed=seed, progress=False)
    save_stage2(a2.stage2, model, s2, h2)


def score_missing_dof(d: Path) -> None:
    """The held-out gap of the ``d = 2`` remedy against the diagnosis' identified model (``<clip>/d2/gap.json``).

    The two charts differ, so only the image error compares like with like,
    and only over one floor (:func:`over_common_floor`); ``eps_q``,
    ``eps_freq`` and the envelope are each read in the model's own chart
    (normalised, hence comparable in scale), ``eps_q`` and ``eps_freq`` over
    the lower chart-noise floor of the two (``common_noise_floor``).
    """
    from lagsplat.diagnose.gap import common_noise_floor, gap_reduction, held_out_gap

    d2 = d / "d2"
    a, a2 = Artifacts.at(d), Artifacts.at(d2)
    model, _ = a2.load_stage2()
    after = held_out_gap(a2.load_chart(), model, a.load_clip(), a2.load_stage1(), EvalConfig(), str(d2))
    before, after = over_common_floor(json.loads((a.report_json).read_text())["gap"]["before"], after)
    before, after = common_noise_floor(before, after)
    write_json(d2 / "gap.json", {"before": before, "after": after, "reduction": gap_reduction(before, after), "d": 2})


def over_common_floor(before: dict, after: dict) -> tuple[dict, dict]:
    """Image error over the lower of two AE floors, for gaps of models with different autoencoders.

    ``image_excess = (eps_I - eps_AE) / eps_AE`` (paper §4.1) subtracts what the
    autoencoder cannot draw. A ``d = 1`` autoencoder of a clip with two moving
    bodies cannot draw the second one's motion, so its floor holds part of the
    gap that the ``d = 2`` remedy is meant to close, and each model over its own
    floor would compare two different things (the remedy's lower floor alone
    raises its ratio). Both are taken over ``min(eps_AE)`` instead: the floor
    the images allow. The per-model floors stay in ``eps_AE``; the one used is
    ``eps_AE_common``. Returns new dicts; ``image_excess`` is ``None`` in both
    when either lacks an image error (latent-only gap).
    """
    if before.get("eps_I") is None or after.get("eps_I") is None:
        return dict(before, image_excess=None), dict(after, image_excess=None)
    floor = min(float(before["eps_AE"]), float(after["eps_AE"]))
    return tuple(dict(g, eps_AE_common=floor, image_excess=(float(g["eps_I"]) - floor) / max(floor, 1e-300)) for g in (before, after))


def score(entry: dict, budget: str, root: Path, timing: dict) -> dict:
    """One result row: truth (read here only), verdict, evidence and held-out gap."""
    d = root / budget / entry["name"]
    a = Artifacts.at(d)
    truth = json.loads((d / "label.json").read_text())["label"]
    rep = json.loads(a.report_json.read_text())
    metrics = a.load_metrics()["metrics"]
    gap = rep["gap"]
    eff = rep["diagnosis"]["effects"]
    top = rep["diagnosis"]["ranking"][:3]
    row = {
        "clip": entry["name"], "system": entry["system"], "truth": truth, "verdict": rep["verdict"], "ok": rep["verdict"] == truth,
        "dBIC": round(eff[0]["delta_bic"], 1) if eff else None,
        "ranking": " ".join(f"{f['effect']}:{f['delta_bic']:.0f}" for f in top),
        "jump": round(metrics.get("chart_jump_ratio", {}).get("value", float("nan")), 2),
        "eps_q": round(gap["before"]["eps_q"], 4), "eps_q_after": round(gap["after"]["eps_q"], 4) if gap["after"] else None,
        "refit": bool(rep["refit"].get("done")), "reliable": bool(rep["reliability"]["reliable"]),
        "gate": (load_chart(a.chart).meta.get("gate") or {}).get("passed"),
    }  # fmt: skip
    red, after = gap.get("reduction") or {}, gap.get("after") or {}
    if rep["verdict"] == "missing_dof" and (d / "d2" / "gap.json").exists():  # the d + 1 remedy (--dof-refit)
        d2 = json.loads((d / "d2" / "gap.json").read_text())
        red, after = d2["reduction"], d2["after"]
        row["refit"] = True
    for k in GAP_METRICS:
        v = red.get(k)
        row[f"red_{k}"] = None if v is None else round(v, 2)
        vc = (gap.get("reduction_vs_control") or {}).get(k)
        row[f"red_ctrl_{k}"] = None if vc is None else round(vc, 2)
    row["s"] = round(sum(timing.values()), 0)
    row["before"] = {k: gap["before"].get(k) for k in GAP_METRICS}  # the identified model's gap (for measurable_gap_medians)
    row["after"] = {k: after.get(k) for k in GAP_METRICS}
    return row


def _hardening(system: str, clip: str) -> bool:
    """Whether the blind clip ``clip`` (``<system>-cubic_stiffness-<seed>``) holds a hardening spring (its ground truth,
    :func:`lagsplat.synth.effect_truth.sample_truth`)."""
    from lagsplat.synth.effect_truth import sample_truth

    return sample_truth(system, "cubic_stiffness", int(clip.rsplit("-", 1)[1]), actuated=False)["effect_params"]["kind"] == "hardening"


def measurable_gap_medians(rows: list[dict]) -> dict[str, dict]:
    """:func:`_common.measurable_gap_medians` over every metric of ``GAP_METRICS``."""
    return measurable_gap_medians_of(rows, GAP_METRICS)


def summarize(rows: list[dict], timings: dict[str, dict], budget: str, markdown: bool = False) -> tuple[str, dict]:
    """The suite's summary over the rows of :func:`score`: the printed report and the ``--json`` record.

    The report holds the per-clip table, the confusion matrix (both by
    :func:`_common.score_verdicts`), the top-1 accuracy, the controls flagged,
    the median held-out gap reductions (over all refit effect clips and over
    :func:`measurable_gap_medians`) and the median wall time per stage.
    ``markdown``: a title line and the scores as list items, for a ``.md``
    file; otherwise the plain lines printed after a run. ``timings``: clip
    name -> stage -> seconds (:func:`run_clip`). The record has ``budget``,
    ``accuracy``, ``controls_flagged``, ``median_reduction``,
    ``median_reduction_vs_control``, ``measurable_gap``, ``rows`` and ``timings``.
    """
    import io

    import pandas as pd

    buf = io.StringIO()
    if markdown:
        print(f"# Blind diagnosis suite: budget {budget}, {len(rows)} clips", file=buf)
    table, acc, flagged, n_controls = score_verdicts([{k: v for k, v in r.items() if k not in ("before", "after", "commit")} for r in rows], file=buf)
    effects = table[(table["truth"] != "none") & table["refit"]]
    def median(col: str) -> float | None:
        return float(np.nanmedian(effects[col].astype(float))) if len(effects) and effects[col].notna().any() else None

    med = {k: median(f"red_{k}") for k in GAP_METRICS}
    med_c = {k: median(f"red_ctrl_{k}") for k in GAP_METRICS}
    per_stage = pd.DataFrame(list(timings.values())).median().round(1).to_dict()
    item, sub = ("- ", "  - ") if markdown else ("", "  ")
    lines = [f"budget: {budget}, clips {len(table)}", f"top-1 accuracy: {acc:.3f} ({int(table['ok'].sum())}/{len(table)})",
             f"controls flagged: {flagged}/{n_controls}"]  # fmt: skip
    hard = [r.clip for r in table.itertuples() if r.truth == "cubic_stiffness" and r.verdict == "none" and _hardening(r.system, r.clip)]
    if hard:  # the realistic suite's reading, beside the strict one
        n_ok = int(table["ok"].sum()) + len(hard)
        lines.append(f"top-1 accuracy with a hardening spring read as nothing significant also counted right (a convex potential can "
                     f"absorb it; the realistic suite's reading): {n_ok / len(table):.3f} ({n_ok}/{len(table)}; {', '.join(hard)})")  # fmt: skip
    rel = table[table["reliable"]]
    lines.append(f"reliable upstream (chart continuous, decoder shows motion; lagsplat.diagnose.report.reliability): {len(rel)}/{len(table)}"
                 + (f"; top-1 accuracy on those {float(rel['ok'].mean()):.3f}" if len(rel) else ""))  # fmt: skip
    if "gate" in table:
        passed = table[table["gate"] == True]  # noqa: E712 (None: a row from before the gate)
        lines.append(f"chart-quality gate passed (lagsplat.chart.gate): {len(passed)}/{len(table)}"
                     + (f"; top-1 accuracy on those {float(passed['ok'].mean()):.3f}" if len(passed) else ""))  # fmt: skip
    lines.append(f"effect clips refit: {len(effects)}/{int((table['truth'] != 'none').sum())}")
    commits = [r["commit"] for r in rows if r.get("commit")]
    if commits:  # rows read by --gather (read_rows) say where they were measured
        lines.append("rows measured at commit: " + commit_counts(commits))
    pct = lambda v: "n/a" if v is None else f"{100 * v:+.0f} %"  # noqa: E731
    for k in GAP_METRICS:
        lines.append(f"median held-out gap reduction, {k}: {pct(med[k])} (vs the same refit without the term: {pct(med_c[k])})")
    meas = measurable_gap_medians(rows)
    lines.append("over the clips whose gap stands out of the no-effect level (the largest of the same system's controls; measurable_gap_medians):")
    print("\n" + "\n".join(item + ln for ln in lines), file=buf)
    for k, m in meas.items():
        print(f"{sub}{k}: {pct(m['median'])} over {m['n']} of {m['n_refit']} clips; "
              f"of the other {m['n_refit'] - m['n']}, {m['n_kept']} stay at or below the level after the refit; "
              f"vs the refit without the term {pct(m['median_vs_control'])}; share of the excess over the level removed "
              f"{'n/a' if m['median_excess_removed'] is None else format(100 * m['median_excess_removed'], '.0f') + ' %'}, "
              f"{m['n_at_level']} of {m['n']} brought to the level or below; every one brought exactly to the level "
              f"would read {pct(m['median_at_level'])}", file=buf)  # fmt: skip
    print(f"{item}median wall time per stage (s, as cached): {per_stage}", file=buf)
    record = {"budget": budget, "accuracy": acc, "controls_flagged": flagged, "median_reduction": med, "median_reduction_vs_control": med_c,
              "measurable_gap": meas, "rows": rows, "timings": timings}  # fmt: skip
    return buf.getvalue(), record


def read_rows(paths: list[str]) -> tuple[list[dict], dict[str, dict], str]:
    """``(rows, timings, budget)`` from the files written by ``--clip ... --row`` (in the order given); each row
    carries the ``commit`` its file was written at (``"not recorded"`` in a file from before the rows held it).

    Raises:
        ValueError: if the files are of different budgets, or two are of the same clip.
    """
    docs = [json.loads(Path(p).read_text()) for p in paths]
    budgets = sorted({d["budget"] for d in docs})
    if len(budgets) != 1:
        raise ValueError(f"--gather: rows of {len(budgets)} budgets ({', '.join(budgets)}); score one budget at a time")
    names = [d["row"]["clip"] for d in docs]
    if len(set(names)) != len(names):
        raise ValueError(f"--gather: a clip given twice: {sorted({n for n in names if names.count(n) > 1})}")
    return [{**d["row"], "commit": d.get("commit", "not recorded")} for d in docs], {d["row"]["clip"]: d["timing"] for d in docs}, budgets[0]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--budget", choices=sorted(BUDGETS), default="cheap")
    ap.add_argument("--only", default="", help="comma-separated substrings of clip names to run")
    ap.add_argument("--clip", default="", help="run exactly this clip of the suite (a name printed by --list)")
    ap.add_argument("--row", default="", help="with --clip: write the clip's scored row and stage timings here (JSON, read by --gather)")
    ap.add_argument("--gather", nargs="+", default=[], metavar="ROW", help="run nothing: score the rows written by --clip ... --row")
    ap.add_argument("--n-per-effect", type=int, default=2)
    ap.add_argument("--results", default="results/diagnosis_bench", help="cache folder (per budget and clip)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=1, help="torch threads")
    ap.add_argument("--force", action="store_true", help="recompute cached artifacts")
    ap.add_argument("--rediagnose", action="store_true", help="recompute only the diagnosis on cached Stage-1/2 artifacts")
    ap.add_argument("--list", action="store_true", help="list the suite and exit")
    ap.add_argument("--dof-refit", action="store_true", help="when the verdict is missing_dof, rerun Stage 1 / chart / Stage 2 with d = 2 and score its gap")
    ap.add_argument("--json", default="", help="write the per-clip rows and the summary here")
    ap.add_argument("--markdown", "--report", dest="markdown", default=None,
                    help="write the summary (per-clip table, confusion matrix, scores) here as markdown "
                         "(default for the whole suite or --gather: results/benchmarks/diagnosis_<budget>.md)")  # fmt: skip
    ap.add_argument("--no-report", action="store_true", help="write no markdown summary")
    ap.add_argument("--refine-iters", type=int, default=None,
                    help="chart refinement iterations (lagsplat.chart.refine_latents; default: the budget's); "
                         "another value than the budget's caches under <results>/<budget>-refine<N>")  # fmt: skip
    ap.add_argument("--refit-epochs", type=int, default=None, help="epochs of the refit's fine-tune (default: the budget's; a cached diagnosis is redone only with --rediagnose)")
    args = ap.parse_args()
    rep = Report("Blind diagnosis suite", None, __file__)
    if args.row and not args.clip:
        ap.error("--row needs --clip (one clip per row file)")
    if args.gather and (args.clip or args.only):
        ap.error("--gather runs nothing: no --clip / --only")
    if args.gather:
        rows, timings, budget = read_rows(args.gather)
        report(rows, timings, budget, args, rep)
        return
    torch.set_num_threads(args.threads)
    if args.refine_iters is not None and args.refine_iters != BUDGETS[args.budget]["refine_iters"]:
        key = f"{args.budget}-refine{args.refine_iters}"
        BUDGETS[key] = {**BUDGETS[args.budget], "refine_iters": args.refine_iters}
        args.budget = key
    if args.refit_epochs is not None:
        BUDGETS[args.budget]["refit_epochs"] = args.refit_epochs

    suite = blind_suite(args.n_per_effect)
    if args.clip:
        suite = [s for s in suite if s["name"] == args.clip]
        if not suite:
            ap.error(f"--clip {args.clip}: not a clip of the suite with --n-per-effect {args.n_per_effect} (see --list)")
    elif args.only:
        keys = [k for k in args.only.split(",") if k]
        suite = [s for s in suite if any(k in s["name"] for k in keys)]
    if args.list:
        for s in suite:
            print(s["name"])
        print(f"{len(suite)} clips")
        return
    root = Path(args.results)
    rows, timings = [], {}
    for entry in suite:
        t0 = time.perf_counter()
        timing = run_clip(entry, args.budget, root, args.seed, args.force, args.dof_refit, args.rediagnose)
        timings[entry["name"]] = timing
        row = score(entry, args.budget, root, timing)
        rows.append(row)
        print(f"{entry['name']:30s} -> {row['verdict']:16s} ({time.perf_counter() - t0:.0f} s this run; stages {timing})", flush=True)
    if not rows:
        print("no clip selected")
        return
    if args.row:
        write_json(args.row, {"budget": args.budget, "commit": git_commit(), "row": rows[0], "timing": timings[rows[0]["clip"]]})
    report(rows, timings, args.budget, args, rep)


def report(rows: list[dict], timings: dict[str, dict], budget: str, args: argparse.Namespace, rep: Report) -> None:
    """Print the summary of ``rows`` (:func:`summarize`); write it to ``args.markdown`` and ``args.json`` when given.

    The markdown goes through ``rep`` (:class:`_common.Report`: command line
    and environment under the title). Without ``--markdown`` it goes to
    ``results/benchmarks/diagnosis_<budget>.md`` when the whole suite was run
    or ``--gather`` scored rows, and nowhere for a subset or ``--no-report``.
    """
    text, record = summarize(rows, timings, budget)
    print(text, end="")
    path = args.markdown
    if path is None and not (args.only or args.clip):
        path = REPORTS / f"diagnosis_{budget}.md"
    if path and not args.no_report:
        title, _, body = summarize(rows, timings, budget, markdown=True)[0].partition("\n")
        rep.title, rep.path = title.removeprefix("# "), Path(path)
        rep.block(body, echo=False)
        extra = {"timings": "stage wall times as measured by the per-clip jobs (`--clip ... --row`) that wrote the rows"} if args.gather else {}
        rep.write(**extra)
    if args.json:
        write_json(args.json, {"args": vars(args), **record})


if __name__ == "__main__":
    main()
