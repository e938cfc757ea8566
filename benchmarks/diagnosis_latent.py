"""Blind check of the effect diagnosis at the latent level (no Stage 1).

Every clip of the blind suite (:func:`lagsplat.synth.effect_clips.blind_suite`: a
pendulum and a cart, each effect twice, controls included) is simulated; its
true 1-D coordinate ``meta["latent"]`` stands in for the encoded chart,
linearly mapped (random seeded scale, sign and offset, then whitened on the
training frames as :func:`lagsplat.chart.fit_whitening` does) and with white
"chart" noise of ``--noise`` times its standard deviation (the diagnosis's
chart-noise estimate, ``Residual.noise_q``, is 0.17 to 0.73 % of the latent std
on the realistic suite's trained charts, median 0.44 %). A plain model is fitted
on the training episodes:

* ``--model lagrangian`` (default): the paper's Lagrangian, ``train_stage2``
  with the default Stage-2 settings and ``--epochs`` epochs;
* ``--model linear``: the closed-form linear oscillator
  :func:`lagsplat.diagnose.fit_linear_oscillator`.

``--suite realistic``: the scored clips of the realistic suite (those with a row in
``results/benchmarks/realistic/``; :func:`lagsplat.synth.realistic.realistic_suite`) instead, their true
trajectory (:func:`lagsplat.synth.realistic.motion_of`, first coordinate per chart
axis, the hidden degree of freedom of ``missing_dof`` left out as the video's 1-D
chart leaves it) split where the pipeline's run split it (``n_train`` of its
committed row in ``results/benchmarks/realistic/``, else
:func:`lagsplat.prepare.auto_train_fraction`): what the diagnosis could read from a
chart that is the truth up to a linear map and noise. With ``--train-periods N`` the
training part is the first ``N`` true periods instead (the short-clip protocol of
``benchmarks/realistic.py --train-periods``, which cuts the same clips so): what a
chart that is the truth could give the diagnosis on so short a record.

The diagnosis (:func:`lagsplat.diagnose.diagnose_chart`, training frames only)
is run without the label, which is read only to score; a hardening spring
(``cubic_stiffness``) read as "none" counts as right on the realistic suite, as its
scoring does (``benchmarks/realistic.py``). Prints one row per
clip, the confusion matrix (rows: truth, columns: verdict), the top-1
accuracy (controls count as correct when the verdict is "none") and the
number of controls flagged.

    python benchmarks/diagnosis_latent.py [--model lagrangian|linear] [--noise 0.01] [--epochs 20]
                                          [--n-per-effect 2] [--suite blind|realistic] [--json out.json]

Writes what it prints to ``results/benchmarks/diagnosis_latent_<model>.md``
(``diagnosis_latent_realistic_<model>.md`` for the realistic suite)
(``--report PATH``, ``--no-report``; a subset, ``--only``, writes one only
when given a path). Scores, not tests: nothing is asserted.
"""

from __future__ import annotations

import argparse
import io
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np
import torch
from _common import REPORTS, Report, realistic_verdict_ok, score_verdicts, short_train_fraction

import lagsplat  # noqa: F401  (OpenMP wait policy before torch)
from lagsplat.chart import Chart
from lagsplat.diagnose import diagnose_chart, fit_linear_oscillator
from lagsplat.io.atomic import write_json
from lagsplat.io.clip import HELD_OUT, TRAIN
from lagsplat.io.common import jsonable
from lagsplat.prepare import auto_train_fraction
from lagsplat.synth.effects import simulate_effect
from lagsplat.synth.effect_clips import blind_suite
from lagsplat.synth.realistic import motion_of, realistic_suite
from lagsplat.train.stage2 import Stage2Config, train_stage2


def noisy_chart(z: np.ndarray, t: np.ndarray, split: np.ndarray, noise: float, rng: np.random.Generator, label: str,
                episode: np.ndarray | None = None, u: np.ndarray | None = None) -> Chart:
    """A :class:`Chart` of a mapped true coordinate ``z [T,d]``: whitened on the training frames, then white noise
    of ``noise`` times its (unit) std drawn from ``rng``; identity metric, no AE error."""
    d = z.shape[1]
    tr = split == TRAIN
    Wc = np.linalg.cholesky(np.linalg.inv(np.cov(z[tr].T, bias=True).reshape(d, d)))
    q = (z - z[tr].mean(0)) @ Wc
    q = q + noise * rng.standard_normal(q.shape)
    I = np.eye(d)
    return Chart(
        mean=np.zeros(d), W=I, W_inv=I, q=q, t=t, split=split, G_bar=I, A=I, ae_mse=np.zeros(len(q)),
        ae_floor_train=0.0, ae_floor_held_out=0.0, height=64, width=64, meta={"label": label}, episode=episode, u=u,
    )  # fmt: skip


def latent_chart(entry: dict, noise: float, seed: int) -> Chart:
    """A 1-D :class:`Chart` from the clip's true latent: random linear map, whitening, white noise (:func:`noisy_chart`)."""
    run = simulate_effect(entry["system"], entry["effect"], entry["seed"], entry["actuated"])
    rng = np.random.default_rng([seed, entry["seed"], len(entry["name"])])
    z = rng.choice([-1.0, 1.0]) * rng.uniform(0.5, 2.0) * run.latent + rng.uniform(-1.0, 1.0)
    return noisy_chart(z[:, None], run.t, run.split, noise, rng, entry["effect"], run.episode, run.u)


def realistic_chart(entry: dict, noise: float, seed: int, train_periods: float | None = None) -> Chart:
    """A :class:`Chart` from a realistic-suite clip's true trajectory, split where the pipeline's run split it
    (``train_periods``: after that many periods of the true motion's spectral peak, instead).

    The first coordinate (both angles of the double pendulum) is linearly mapped, then whitened and given
    noise by :func:`noisy_chart`, as :func:`latent_chart` does.
    """
    motion = motion_of(entry)
    d = 2 if entry["system"] == "double_pendulum" else 1
    x = motion.q[:, :d]
    row = REPORTS / "realistic" / f"{entry['name']}.json"
    n_train = json.loads(row.read_text()).get("n_train") if row.exists() else None
    if train_periods is not None:  # as benchmarks/realistic.py cuts a short clip
        n_train = int(round(short_train_fraction(motion.q, motion.t, train_periods) * len(x)))
    elif not n_train:
        fps = 1.0 / float(np.median(np.diff(motion.t)))
        n_train = int(round(auto_train_fraction(len(x), motion.f0_hz, fps) * len(x)))
    split = np.full(len(x), HELD_OUT, np.int8)
    split[: int(n_train)] = TRAIN
    rng = np.random.default_rng([seed, entry["seed"], len(entry["name"])])
    z = x @ rng.uniform(0.5, 2.0, (d, d)) * rng.choice([-1.0, 1.0]) + rng.uniform(-1.0, 1.0, d)
    return noisy_chart(z, motion.t, split, noise, rng, entry["effect"])


def fit_plain(chart: Chart, kind: str, epochs: int, seed: int):
    """The plain model on the training frames."""
    if kind == "linear":
        segs = chart.segments(TRAIN)
        us = [chart.u[s] for s in segs] if chart.n_u else None
        return fit_linear_oscillator([chart.q[s] for s in segs], float(np.median(np.diff(chart.t))), us)
    model, _ = train_stage2(chart, Stage2Config(epochs=epochs), seed=seed, progress=False)
    return model


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--model", choices=("lagrangian", "linear"), default="lagrangian")
    ap.add_argument("--noise", type=float, default=0.01, help="chart noise, fraction of the latent std")
    ap.add_argument("--epochs", type=int, default=20, help="Stage-2 epochs (lagrangian)")
    ap.add_argument("--n-per-effect", type=int, default=2, help="blind suite: clips per effect")
    ap.add_argument("--suite", choices=("blind", "realistic"), default="blind",
                    help="the project's blind suite, or the realistic suite's true trajectories (128 px clips)")
    ap.add_argument("--only", default="", help="comma-separated substrings of clip names to run")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", default="", help="write the per-clip results here")
    ap.add_argument("--report", type=Path, default=None,
                    help="write the Markdown report here (default: results/benchmarks/diagnosis_latent_<model>.md, none with --only)")  # fmt: skip
    ap.add_argument("--no-report", action="store_true", help="print only, write no report")
    ap.add_argument("--train-periods", type=float, default=None,
                    help="realistic suite: train on the first N true periods only (the short-clip protocol)")  # fmt: skip
    args = ap.parse_args()
    if args.train_periods is not None and args.suite != "realistic":
        ap.error("--train-periods needs --suite realistic")
    torch.set_num_threads(1)
    short = "" if args.train_periods is None else f"_short{args.train_periods:g}"
    name = f"diagnosis_latent_{'realistic_' if args.suite == 'realistic' else ''}{args.model}{short}"
    path = None if args.no_report else args.report or (None if args.only else REPORTS / f"{name}.md")
    title = "Realistic suite's true trajectories" if args.suite == "realistic" else "Blind diagnosis at the latent level"
    if args.train_periods is not None:
        title += f", training frames cut to {args.train_periods:g} periods"
    rep = Report(f"{title}: model {args.model}, chart noise {args.noise:g}", path, __file__)

    if args.suite == "realistic":
        suite = [e for e in realistic_suite() if (REPORTS / "realistic" / f"{e['name']}.json").exists()]
        make_chart = lambda e, noise, seed: realistic_chart(e, noise, seed, args.train_periods)  # noqa: E731
    else:
        suite = blind_suite(args.n_per_effect)
        make_chart = latent_chart
    if args.only:
        keys = args.only.split(",")
        suite = [s for s in suite if any(k in s["name"] for k in keys)]
    rows, records = [], []
    for entry in suite:
        t0 = time.perf_counter()
        chart = make_chart(entry, args.noise, args.seed)
        model = fit_plain(chart, args.model, args.epochs, args.seed)
        diag, _ = diagnose_chart(model, chart)
        truth = entry["effect"]
        top = diag.ranking[:3]
        rows.append({
            "clip": entry["name"], "truth": truth, "verdict": diag.winner,
            "ok": realistic_verdict_ok(entry["name"], diag.winner) if args.suite == "realistic" else diag.winner == truth,
            "dBIC": round(diag.effects[0].delta_bic, 1) if diag.effects else None,
            "R2": round(diag.effects[0].r2, 2) if diag.effects else None,
            "runner-up": " ".join(f"{f.effect}:{f.delta_bic:.0f}" for f in top),
            "resid/noise": round(diag.null["excess_over_noise"], 2), "s": round(time.perf_counter() - t0, 1),
        })  # fmt: skip
        records.append({"entry": entry, "diagnosis": diag.to_dict()})
        print(f"{entry['name']:28s} -> {diag.winner}", flush=True)

    buf = io.StringIO()
    table, acc, flagged, n_controls = score_verdicts(rows, file=buf)
    rep.block(buf.getvalue())
    print()
    rep.text(
        f"model: {args.model}, noise {args.noise:g}, clips {len(table)}",
        f"top-1 accuracy: {acc:.3f} ({int(table['ok'].sum())}/{len(table)})",
        f"controls flagged: {flagged}/{n_controls}",
    )
    rep.write()
    if args.json:
        write_json(args.json, {"args": jsonable(vars(args)), "accuracy": acc, "controls_flagged": flagged, "clips": records})


if __name__ == "__main__":
    main()
