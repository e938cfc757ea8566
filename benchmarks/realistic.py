"""Score the pipeline on the realistic suite (lagsplat.synth.realistic) against the ground truth.

Per clip (``--clip``): run ``python -m lagsplat all system=realistic`` on the clip as a new user would
(source, frame rate and working resolution only; ``conf/system/realistic.yaml``), then write one row:
the identified frequency against the truth's (the same spectral-peak estimator on the held-out frames
of the true trajectory), the chart's jump ratio, and the stage that stopped the run with its one-line
reason when it did not finish. ``--gather`` turns rows into ``results/benchmarks/realistic.md`` and
``.json``: per-clip table, median and 90th percentile of the frequency error, crashes and stops.

    python benchmarks/realistic.py --clip pendulum-none-s0-128 --clips data/cache/realistic --results results/realistic --row R.json
    python benchmarks/realistic.py --gather results/benchmarks/realistic/*.json --out results/benchmarks/realistic.md
    snakemake -c2 realistic_scores          # both, one job per clip

``--from-stage2``: Stage 2 and the evaluation again on the Stage-1 autoencoder and chart already in
``--results`` (a Stage-2 change re-scored without training Stage 1 again); the row's ``wall_s`` is then
theirs only.

``--true-law``: on the clip's finished run, score its ground-truth law written in the run's chart
(``benchmarks/_oracle.py``) with the run's evaluation settings: ``eps_q_true_law`` is what a model with no
gap at all scores on this chart, about the lowest held-out ``eps_q`` a refit can be expected to reach (1-DOF clips with an effect
law; not the double pendulum or a missing degree of freedom). ``--gather`` reports the median reduction a
refit that recovered the exact law would show beside the measured one. The same flag runs the diagnosis's
selection with the clip's *control* law (the true law without its effect) as the model:
``verdict_true_control`` is what the diagnosis names when Stage 2 misfits nothing, and ``--gather`` reports its
top-1 beside the pipeline's on the same clips.

Short clips (``--train-periods 3 --from-results results/realistic``): the diagnosis on a clip whose
training part is only three periods of the motion. The full run's folder is copied and the split is
moved (``system.split.train_fraction`` = three true periods over the clip's length), then ingest, chart,
Stage 2, evaluation and diagnosis run again on it; the Stage-1 autoencoder is the full run's, which
trained on every frame either way (the split decides only what Stage 2 and the diagnosis read).

Scoring of the diagnosis: ``diagnosis_ok`` when the verdict names the clip's effect, or, for a
hardening spring (``cubic_stiffness``), also "nothing significant" (a convex potential can absorb it);
``diagnosis_exact`` is the strict reading.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from _common import Report, commit_counts, git_commit, measurable_gap_medians, realistic_verdict_ok, short_train_fraction  # this script's folder

from lagsplat.artifacts import Artifacts  # noqa: E402
from lagsplat.io.atomic import write_json  # noqa: E402
from lagsplat.synth.realistic import clip_spec  # noqa: E402
from lagsplat.timeseries import spectral_peak_frequency  # noqa: E402

def truth_frequency(truth_npz: Path, n_train: int | None = None) -> float:
    """Frequency (Hz) of the true first coordinate on the held-out frames (after ``n_train``; default: the
    last 20 %), by the evaluation's spectral peak; over the whole clip for a clip identified without
    held-out frames (``n_train`` all of it), as its in-sample ``f_sim_hz`` is read."""
    z = np.load(truth_npz)
    q, t = z["q"], z["t"]
    start = int(0.8 * len(q)) if n_train is None else n_train
    ho = q[start if start < len(q) - 8 else 0 :, :1]
    return float(spectral_peak_frequency(ho, float(np.median(np.diff(t)))))


def run_clip(name: str, clips: Path, results: Path, threads: int, extra: list[str], stage: str = "all") -> tuple[int, str, float]:
    """Run the pipeline (``stage``: ``all``, or ``diagnose`` on its artifacts) on one clip; returns ``(exit code, last stderr line, wall seconds)``."""
    spec = clip_spec(name)
    d = 2 if spec["system"] == "double_pendulum" else 1
    cmd = [sys.executable, "-m", "lagsplat", stage, "system=realistic", f"system.name={name}", f"system.title={name}",
           f"system.source.path={clips / (name + '.mp4')}", f"system.d={d}", f"results_dir={results}", f"threads={threads}",
           "progress=false", *extra]  # fmt: skip
    t0 = time.perf_counter()
    r = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    sys.stdout.write(r.stdout)
    sys.stderr.write(r.stderr)
    lines = [ln for ln in r.stderr.strip().splitlines() if ln.startswith("lagsplat ") or "Error" in ln]
    return r.returncode, (lines[-1] if lines else (r.stderr.strip().splitlines() or [""])[-1]), time.perf_counter() - t0


def row_of(name: str, clips: Path, results: Path, code: int, reason: str, wall_s: float) -> dict:
    """One scored row of the suite (see the module docstring)."""
    spec = clip_spec(name)
    art = Artifacts.for_run(results, name)
    n_train = art.load_clip().meta["split"]["n_train"] if art.clip.exists() else None  # the split the run chose
    row = {**spec, "exit_code": code, "wall_s": round(wall_s, 1), "commit": git_commit(), "load_1min": round(os.getloadavg()[0], 2), "f_truth_hz": truth_frequency(clips / f"{name}.truth.npz", n_train), "n_train": n_train}
    if art.chart.exists():  # the chart-quality gate, also for a run that stopped at it
        gate = art.load_chart().meta.get("gate") or {}
        row.update(gate_passed=gate.get("passed"), gate={k: round(v["value"], 4) for k, v in gate.get("checks", {}).items()})
    if art.stage1.exists():
        import torch

        attempts = torch.load(art.stage1, map_location="cpu", weights_only=False)["history"].get("attempts", [])
        row.update(stage1_attempts=len(attempts))
    m = art.load_metrics()
    if code != 0 or m is None:
        return {**row, "status": "stopped" if code == 1 else "crashed", "reason": reason}
    mm = m["metrics"]
    val = lambda k: (mm.get(k) or {}).get("value")  # noqa: E731
    f_sim = val("f_sim_hz")
    row.update(
        status="ok",
        f_sim_hz=f_sim,
        f_enc_hz=val("f_enc_hz"),
        eps_freq=val("eps_freq"),
        eps_freq_truth=abs(f_sim - row["f_truth_hz"]) / row["f_truth_hz"] if f_sim else None,
        eps_q=val("eps_q"),
        eps_I_over_AE=val("eps_I_over_AE"),
        chart_jump_ratio=val("chart_jump_ratio"),
    )
    return row


def diagnosis_of(name: str, results: Path, code: int, reason: str, wall_s: float) -> dict:
    """The diagnosis's fields of a row: the truth, the verdict, and the held-out gap reduction of the refit.

    ``diagnosis_ok``: the verdict names the clip's effect (``none`` for a clip without one); a chart
    that failed the gate must read ``cannot_diagnose``, which is then counted apart, not as right.
    """
    spec = clip_spec(name)
    rj = Artifacts.for_run(results, name).report_json
    rep = json.loads(rj.read_text()) if code == 0 and rj.exists() else None
    if rep is None:
        return {"diagnosis_status": "crashed", "diagnosis_reason": reason, "diagnosis_wall_s": round(wall_s, 1)}
    gap = rep.get("gap") or {}
    red = (gap.get("reduction") or {}).get("eps_q")
    confirmed = bool((gap.get("held_out_check") or {}).get("confirmed"))
    f_refit = (gap.get("after") or {}).get("f_sim_hz") if confirmed else None
    exact = rep["verdict"] == spec["effect"]
    ok = realistic_verdict_ok(name, rep["verdict"])
    return {"diagnosis_status": "ok", "truth_effect": spec["effect"], "verdict": rep["verdict"], "verdict_text": rep["verdict_text"],
            "diagnosis_ok": ok, "diagnosis_exact": exact, "gap_reduction_eps_q": red, "refit_confirmed": confirmed,
            "f_sim_refit_hz": f_refit, "diagnosis_wall_s": round(wall_s, 1)}  # fmt: skip


def true_law_of(name: str, clips: Path, results: Path, floor_draws: int = 8) -> dict:
    """The row's ``eps_q_true_law`` (with its noise floor and the chart map's rms): the clip's ground-truth law
    written in the run's chart and scored by the run's own evaluation settings (``benchmarks/_oracle.py``);
    and ``verdict_true_control`` (with ``true_control_ok``, scored as ``diagnosis_ok``): what the diagnosis's
    selection names with the clip's control law as the model (:func:`_oracle.true_control_diagnosis`, default
    diagnosis settings). ``{}`` where there is no 1-DOF law (double pendulum, missing degree of freedom) or the run
    did not reach the evaluation (no chart, or stopped at the chart's quality gate)."""
    from _oracle import true_control_diagnosis, true_law_gap  # this script's folder
    from omegaconf import OmegaConf

    from lagsplat.evaluate import EvalConfig

    spec = clip_spec(name)
    art = Artifacts.for_run(results, name)
    if spec["system"] == "double_pendulum" or spec["effect"] == "missing_dof" or not (art.chart.exists() and art.config("evaluate").exists()):
        return {}
    cfg = EvalConfig(**OmegaConf.to_container(OmegaConf.load(art.config("evaluate")).evaluate, resolve=True))
    chart, truth = art.load_chart(), clips / f"{name}.truth.npz"
    g = true_law_gap(chart, truth, spec["system"], cfg, floor_draws)
    verdict = true_control_diagnosis(chart, truth, spec["system"]).winner
    return {"eps_q_true_law": g["eps_q"], "eps_q_true_law_floor": g["eps_q_floor"], "chart_map_rms": g["chart_map_rms"],
            "verdict_true_control": verdict, "true_control_ok": realistic_verdict_ok(name, verdict)}  # fmt: skip


def _gap_row(row: dict) -> dict:
    """A realistic row in the form :func:`_common.measurable_gap_medians` reads: held-out ``eps_q`` before the refit
    (the identified model's) and after it (``before * (1 - reduction)``)."""
    red, before = row.get("gap_reduction_eps_q"), row.get("eps_q")
    after = None if red is None or before is None else before * (1.0 - red)
    return {"system": row.get("system"), "truth": row.get("truth_effect"), "refit": red is not None,
            "before": {"eps_q": before}, "after": {"eps_q": after}, "red_eps_q": red,
            "true_law": {"eps_q": row.get("eps_q_true_law")}}  # fmt: skip


def eps_freq_after_diagnosis(row: dict) -> float | None:
    """Frequency error against the truth of the model the diagnosis leaves: the refit's free-oscillation
    frequency when its held-out check confirmed the effect, else the Stage-2 model's; ``None`` for a row
    without metrics or without a diagnosis scored by this version of the script (no ``refit_confirmed``)."""
    if row.get("status") != "ok" or row.get("f_sim_hz") is None or "refit_confirmed" not in row:
        return None
    f = row["f_sim_refit_hz"] if row["refit_confirmed"] and row.get("f_sim_refit_hz") else row["f_sim_hz"]
    return abs(f - row["f_truth_hz"]) / row["f_truth_hz"]


def short_clip(name: str, clips: Path, source: Path, results: Path, threads: int, extra: list[str], periods: float) -> dict:
    """The diagnosis with only ``periods`` true periods of training frames (module docstring, "Short clips"): one row.

    Raises:
        FileNotFoundError: if ``source`` has no finished run of the clip (its Stage-1 autoencoder is reused).
    """
    src = Artifacts.for_run(source, name)
    if not src.stage1.exists():
        raise FileNotFoundError(f"{src.stage1}: run the full clip first (--clip {name} --results {source})")
    z = np.load(clips / f"{name}.truth.npz")
    frac = short_train_fraction(z["q"], z["t"], periods)
    dst = Artifacts.for_run(results, name).system_dir
    if dst.exists():
        shutil.rmtree(dst)
    shutil.copytree(src.system_dir, dst, ignore=shutil.ignore_patterns("diagnosis", "variants", "figures"))
    over = [*extra, f"+system.split.train_fraction={frac}"]
    code, reason, wall = 0, "", 0.0
    for stage in ("ingest", "chart", "stage2", "evaluate"):
        code, reason, w = run_clip(name, clips, results, threads, over, stage=stage)
        wall += w
        if code != 0:
            break
    row = {**row_of(name, clips, results, code, reason, wall), "train_periods": periods, "train_fraction": frac}
    if code == 0:
        code, reason, w = run_clip(name, clips, results, threads, over, stage="diagnose")
        row.update(diagnosis_of(name, results, code, reason, w), diagnosis_commit=git_commit())
    return row


def gather(rows: list[dict], out_md: Path, argv: list[str] | None = None) -> dict:
    """Write the summary table (Markdown) and the JSON record beside it; returns the summary.

    ``argv``: the command line's arguments, for the report (default ``sys.argv[1:]``).
    """
    ok = [r for r in rows if r["status"] == "ok" and r.get("eps_freq_truth") is not None]
    e = np.array([r["eps_freq_truth"] for r in ok])
    summary = {
        "n_clips": len(rows), "n_ok": len(ok), "n_stopped": sum(r["status"] == "stopped" for r in rows),
        "n_crashed": sum(r["status"] == "crashed" for r in rows), "systems": sorted({r["system"] for r in rows}),
        "eps_freq_truth_median": float(np.median(e)) if len(e) else None,
        "eps_freq_truth_p90": float(np.percentile(e, 90)) if len(e) else None,
        "share_within_5pct": float(np.mean(e <= 0.05)) if len(e) else None,
        "n_gate_passed": sum(bool(r.get("gate_passed")) for r in rows),
        "share_within_5pct_of_gate_passed": float(np.mean([r["eps_freq_truth"] <= 0.05 for r in ok if r.get("gate_passed")]))
        if any(r.get("gate_passed") for r in ok) else None,
        "wall_s_median": float(np.median([r["wall_s"] for r in rows])) if rows else None,
        "wall_s_max": float(max(r["wall_s"] for r in rows)) if rows else None,
    }  # fmt: skip
    ea = np.array([x for x in map(eps_freq_after_diagnosis, rows) if x is not None])
    if len(ea):  # the second reading: the model after the diagnosis's confirmed refit (Stage 2's where none)
        summary["after_diagnosis"] = {"n": len(ea), "eps_freq_truth_median": float(np.median(ea)),
                                      "eps_freq_truth_p90": float(np.percentile(ea, 90)), "share_within_5pct": float(np.mean(ea <= 0.05))}  # fmt: skip
    dg = [r for r in rows if r.get("diagnosis_status") == "ok"]
    if dg:
        passed = [r for r in dg if r.get("gate_passed")]
        ctrl = [r for r in passed if r["truth_effect"] == "none"]
        reds = [r["gap_reduction_eps_q"] for r in passed if r["truth_effect"] != "none" and r.get("gap_reduction_eps_q") is not None]
        summary["diagnosis"] = {
            "n_diagnosed": len(dg), "n_on_passed_charts": len(passed),
            "top1": float(np.mean([r["diagnosis_ok"] for r in passed])) if passed else None,
            "controls_flagged": sum(r["verdict"] not in ("none", "cannot_diagnose") for r in ctrl), "n_controls": len(ctrl),
            "failed_gate_read_cannot_diagnose": sum(r["verdict"] == "cannot_diagnose" for r in dg if r.get("gate_passed") is False),
            "n_failed_gate": sum(r.get("gate_passed") is False for r in dg),
            "median_gap_reduction_eps_q": float(np.median(reds)) if reds else None,
            "measurable_gap": measurable_gap_medians([_gap_row(r) for r in passed], ("eps_q",))["eps_q"],
        }  # fmt: skip
        oracle = [r for r in passed if r.get("verdict_true_control") is not None]
        if oracle:  # the selection with a perfect model of the control class (--true-law)
            summary["diagnosis"]["true_control"] = {
                "n": len(oracle), "top1": float(np.mean([r["true_control_ok"] for r in oracle])),
                "top1_pipeline": float(np.mean([r["diagnosis_ok"] for r in oracle])),
                "controls_flagged": sum(r["verdict_true_control"] != "none" for r in oracle if r["truth_effect"] == "none"),
                "n_controls": sum(r["truth_effect"] == "none" for r in oracle),
            }  # fmt: skip
    commits = sorted({r.get("commit", "unknown") for r in rows})
    summary["commits"] = commits
    L = [f"{summary['n_clips']} clips over {len(summary['systems'])} systems: {summary['n_ok']} with metrics, "
         f"{summary['n_stopped']} stopped with a reason, {summary['n_crashed']} crashed; the chart passed the quality gate "
         f"on {summary['n_gate_passed']}. Rows measured at commit {commit_counts([r.get('commit', 'unknown') for r in rows])}"
         + (f"; diagnoses at commit {commit_counts([r['diagnosis_commit'] for r in rows if r.get('diagnosis_commit')])}"
            if any(r.get("diagnosis_commit") for r in rows) else "") + ".", ""]  # fmt: skip
    if summary["share_within_5pct_of_gate_passed"] is not None:
        L += [f"Of the clips whose chart passed the gate and that have metrics, {100 * summary['share_within_5pct_of_gate_passed']:.0f} % "
              "are within 5 % of the true frequency.", ""]  # fmt: skip
    if len(e):
        L += [f"Frequency error against the truth: median {100 * summary['eps_freq_truth_median']:.2f} %, 90th percentile "
              f"{100 * summary['eps_freq_truth_p90']:.2f} %, within 5 %: {100 * summary['share_within_5pct']:.0f} % of the clips with metrics.", ""]  # fmt: skip
    if "after_diagnosis" in summary:
        A = summary["after_diagnosis"]
        L += [f"The same after the diagnosis (the refit's frequency where its held-out check confirmed an effect, Stage 2's "
              f"elsewhere; {A['n']} clips scored so): median {100 * A['eps_freq_truth_median']:.2f} %, 90th percentile "
              f"{100 * A['eps_freq_truth_p90']:.2f} %, within 5 %: {100 * A['share_within_5pct']:.0f} %.", ""]  # fmt: skip
    if "diagnosis" in summary:
        D = summary["diagnosis"]
        top1 = "n/a" if D["top1"] is None else f"{100 * D['top1']:.0f} %"
        red = "n/a" if D["median_gap_reduction_eps_q"] is None else f"{100 * D['median_gap_reduction_eps_q']:+.0f} %"
        L += [f"Diagnosis ({D['n_diagnosed']} clips): top-1 {top1} over the {D['n_on_passed_charts']} whose chart passed the gate; "
              f"controls flagged {D['controls_flagged']}/{D['n_controls']}; charts that failed the gate read cannot_diagnose "
              f"{D['failed_gate_read_cannot_diagnose']}/{D['n_failed_gate']}; median held-out eps_q change after the refit {red}.", ""]  # fmt: skip
        if "true_control" in D:
            O = D["true_control"]
            L += [f"With the clip's control law as the model (`--true-law`: its ground-truth law without the effect, written in the "
                  f"run's chart; the selection alone, no Stage-2 misfit), the diagnosis's top-1 is {100 * O['top1']:.0f} % over the "
                  f"{O['n']} 1-DOF clips it applies to, controls flagged {O['controls_flagged']}/{O['n_controls']}; the pipeline's "
                  f"top-1 on the same clips is {100 * O['top1_pipeline']:.0f} %.", ""]  # fmt: skip
        m = D["measurable_gap"]
        if m["levels"]:
            lv = ", ".join(f"{k} {v:.3f}" for k, v in sorted(m["levels"].items()))
            med = "n/a" if m["median"] is None else f"{100 * m['median']:+.0f} %"
            L += [f"Over the clips with a measurable gap (held-out eps_q above the largest of the same system's controls: {lv}): "
                  f"median eps_q change after the refit {med} ({m['n']} of the {m['n_refit']} refits; of the others, {m['n_kept']} "
                  "stay at or below the no-effect level after it).", ""]  # fmt: skip
            if m["median_excess_removed"] is not None:
                L += [f"On the same clips, the share of the gap's excess over the no-effect level that the refit removes "
                      f"(min(1, (before - after) / (before - level))): median {100 * m['median_excess_removed']:.0f} %; "
                      f"{m['n_at_level']} of the {m['n']} refits bring eps_q to the level or below. Had every one of them "
                      f"brought eps_q exactly to the level, the median eps_q change would read {100 * m['median_at_level']:+.0f} % "
                      "(1 - level / before).", ""]  # fmt: skip
            if m.get("median_true_law") is not None:
                L += [f"The clips' own ground-truth law, written in each clip's chart and scored by the same protocol "
                      f"(`--true-law`; {m['n_true_law']} of the {m['n']} measurable clips): had every refit recovered it exactly, "
                      f"the median eps_q change would read {100 * m['median_true_law']:+.0f} % (1 - true law / before); "
                      f"{m['n_at_true_law']} of those refits already score at or below the true law.", ""]  # fmt: skip
    L += [f"Wall time per clip: median {summary['wall_s_median']:.0f} s, max {summary['wall_s_max']:.0f} s.", "",
          "| clip | status | gate | attempts | f_truth (Hz) | f_sim (Hz) | eps_freq vs truth | after diagnosis | eps_q | eps_q after refit | eps_q true law | eps_I / eps_AE | continuity | coverage | saturation | verdict | verdict, true control law | reason |",
          "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    fmt = lambda v, f: "" if v is None else format(v, f)  # noqa: E731
    for r in sorted(rows, key=lambda r: r["name"]):
        g = r.get("gate") or {}
        gate = {True: "passed", False: "failed"}.get(r.get("gate_passed"), "")
        L.append(f"| {r['name']} | {r['status']} | {gate} | {r.get('stage1_attempts', '')} | {r['f_truth_hz']:.3f} | {fmt(r.get('f_sim_hz'), '.3f')} | "
                 f"{fmt(r.get('eps_freq_truth'), '.2%')} | {fmt(eps_freq_after_diagnosis(r), '.2%')} | {fmt(r.get('eps_q'), '.3f')} | "
                 f"{fmt(_gap_row(r)['after']['eps_q'], '.3f')} | {fmt(r.get('eps_q_true_law'), '.3f')} | {fmt(r.get('eps_I_over_AE'), '.2f')} | "
                 f"{fmt(g.get('continuity'), '.1f')} | {fmt(g.get('coverage'), '.2f')} | {fmt(g.get('saturation'), '.2f')} | {r.get('verdict', '')} | {r.get('verdict_true_control', '')} | {r.get('reason', '').replace('|', chr(92) + '|')} |")  # fmt: skip
    periods = sorted({r["train_periods"] for r in rows if r.get("train_periods") is not None})
    short = f", training frames cut to {', '.join(f'{p:g}' for p in periods)} periods" if periods else ""
    rep = Report(f"Realistic suite (MuJoCo-rendered clips) against the ground truth{short}", out_md, __file__, argv)
    rep.block("\n".join(L), echo=False)  # the command line and the environment go under the title
    rep.write(timings="wall time per clip as measured by the per-clip jobs (`--clip ... --row`)")
    write_json(out_md.with_suffix(".json"), {"summary": summary, "rows": rows})
    return summary


def main(argv: list[str] | None = None) -> int:
    """Entry point (module docstring)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--clip")
    ap.add_argument("--clips", type=Path, default=ROOT / "data" / "cache" / "realistic")
    ap.add_argument("--results", type=Path, default=ROOT / "results" / "realistic")
    ap.add_argument("--row", type=Path, help="where the clip's row goes (JSON)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--diagnose", action="store_true", help="also run the diagnosis (python -m lagsplat diagnose) and score its verdict; "
                    "with an existing --row, only the diagnosis, on the cached artifacts")
    ap.add_argument("--true-law", action="store_true", help="also score the clip's ground-truth law in the run's chart "
                    "(eps_q_true_law: what a perfect model scores; benchmarks/_oracle.py) and run the diagnosis's selection with its "
                    "control law as the model (verdict_true_control), on the run's artifacts")
    ap.add_argument("--train-periods", type=float, help="short clip: only this many true periods of training frames (needs --from-results)")
    ap.add_argument("--from-results", type=Path, help="the full runs whose Stage-1 autoencoders the short clips reuse")
    ap.add_argument("--from-stage2", action="store_true", help="rerun Stage 2 and the evaluation only, on the clip's Stage-1 autoencoder "
                    "and chart already in --results (a Stage-2 change re-scored without training Stage 1 again)")
    ap.add_argument("--gather", nargs="+", type=Path, help="rows to summarise")
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "benchmarks" / "realistic.md")
    ap.add_argument("extra", nargs="*", help="Hydra overrides for every stage, e.g. stage1.steps=500")
    a = ap.parse_args(argv)
    if a.gather:
        s = gather([json.loads(p.read_text()) for p in a.gather], a.out, argv)
        print(json.dumps(s, indent=1))
        return 0
    if not a.clip or not a.row:
        ap.error("give --clip and --row, or --gather")
    missing = [p for p in (a.clips / f"{a.clip}.mp4", a.clips / f"{a.clip}.truth.npz") if not p.exists()]
    if missing:  # before any stage runs: the row needs the clip's ground truth
        ap.error(f"{', '.join(map(str, missing))}: not found (render it: python -m lagsplat.synth.realistic --clip {a.clip} --out {a.clips})")
    if a.train_periods is not None:
        if a.from_results is None:
            ap.error("--train-periods needs --from-results (the full runs)")
        row = short_clip(a.clip, a.clips, a.from_results, a.results, a.threads, a.extra, a.train_periods)
        if a.true_law:
            row.update(true_law_of(a.clip, a.clips, a.results))
        write_json(a.row, row)
        print(json.dumps(row))
        return 0
    if a.from_stage2:
        if not Artifacts.for_run(a.results, a.clip).chart.exists():
            ap.error(f"--from-stage2: {a.results / a.clip} has no chart (run the clip without --from-stage2 first)")
        wall = 0.0
        for stage in ("stage2", "evaluate"):
            code, reason, w = run_clip(a.clip, a.clips, a.results, a.threads, a.extra, stage=stage)
            wall += w
            if code != 0:
                break
        row = row_of(a.clip, a.clips, a.results, code, reason, wall)
        write_json(a.row, row)
    elif a.row.exists() and (a.diagnose or a.true_law):  # the pipeline's row is there: the diagnosis / true law only, on its artifacts
        row = json.loads(a.row.read_text())
    else:
        code, reason, wall = run_clip(a.clip, a.clips, a.results, a.threads, a.extra)
        row = row_of(a.clip, a.clips, a.results, code, reason, wall)
        write_json(a.row, row)
    if a.diagnose and Artifacts.for_run(a.results, a.clip).chart.exists():
        code, reason, wall = run_clip(a.clip, a.clips, a.results, a.threads, a.extra, stage="diagnose")
        row.update(diagnosis_of(a.clip, a.results, code, reason, wall), diagnosis_commit=git_commit())
        write_json(a.row, row)
    if a.true_law:
        row.update(true_law_of(a.clip, a.clips, a.results))
        write_json(a.row, row)
    print(json.dumps(row))
    return 0


if __name__ == "__main__":
    sys.exit(main())
