"""Calibrate and check the 90 % intervals of the identified frequency and damping ratio on the realistic suite.

The realistic suite's clips are split once, by a rule fixed before any calibration (:func:`half`: the parity of
the SHA-1 of the clip's name), into a calibration half and a test half. ``--calibrate`` reads each run's
``metrics.json`` (``f_sim_hz``, ``eps_freq``, ``zeta_sim``, ``zeta_enc``; run ``python -m lagsplat evaluate`` on
older runs first) and the clip's ground truth (the true frequency and damping ratio on the held-out frames, by
the evaluation's own estimators), computes the split-conformal constants on the calibration half (scores ``|f_truth / f_sim - 1| / s_f`` and
``|zeta_truth - zeta_sim| / s_z``, the intervals' own half-widths per unit ``k``)
(:mod:`lagsplat.evaluate.intervals`), writes them to the package's calibration file, and reports the coverage
of the test half's true frequency and damping ratio by its intervals, per system
(``results/benchmarks/intervals.md``).

    python benchmarks/intervals.py --calibrate --runs /scratch/realistic_runs --clips data/cache/realistic

``--calibrate-on all --test-runs DIR`` calibrates on every run of ``--runs`` and measures the coverage on the
runs of ``DIR`` instead (other rendered clips of known truth, e.g. the backdrop renders, that the calibration
never saw).
"""

from __future__ import annotations

import argparse
import hashlib
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import REPORTS, Report, git_commit  # this script's folder
from realistic import truth_frequency  # this script's folder

from lagsplat import metrics as lmetrics
from lagsplat.artifacts import Artifacts
from lagsplat.evaluate.in_sample import damping_ratio
from lagsplat.evaluate.intervals import CALIBRATION_FILE, LEVEL, conformal_k, damping_scale, frequency_scale, intervals
from lagsplat.io.atomic import write_json
from lagsplat.io.clip import HELD_OUT
from lagsplat.synth.realistic import clip_spec
from lagsplat.timeseries import spectral_peak_frequency


def half(name: str) -> str:
    """``"calibration"`` or ``"test"``: the clip's half, fixed by the parity of the SHA-1 of its name."""
    return "test" if int(hashlib.sha1(name.encode()).hexdigest(), 16) % 2 else "calibration"


def truth_damping(truth_npz: Path, clip, sigma: float = 1.0) -> float | None:
    """The damping ratio of the true first coordinate over the clip's longest held-out segment, from the
    evaluation's first rollout frame (:func:`lagsplat.metrics.rollout_start`), by the evaluation's estimator."""
    z = np.load(truth_npz)
    q, t = z["q"][:, 0].astype(float), z["t"]
    dt = float(np.median(np.diff(t)))
    first = int((clip.meta.get("frames") or [0])[0] or 0)
    held = clip.segments(HELD_OUT)
    if not held:
        return None
    seg = first + max(held, key=len)
    lo = lmetrics.rollout_start(sigma, len(seg), 16)
    p = q[seg[lo:]]
    return damping_ratio(p - p.mean(), dt, float(spectral_peak_frequency(p[:, None], dt)))


def row(name: str, runs: Path, clips: Path) -> dict | None:
    """One clip's quantities, or ``None`` without metrics."""
    art = Artifacts.for_run(runs, name)
    m = art.load_metrics() if art.metrics.exists() else None
    if m is None or "f_sim_hz" not in m["metrics"]:
        return None
    mm = m["metrics"]
    clip = art.load_clip()
    val = lambda k: (mm.get(k) or {}).get("value")  # noqa: E731
    npz = clips / f"{name}.truth.npz"
    return {"clip": name, "system": clip_spec(name)["system"], "half": half(name), "f_sim_hz": val("f_sim_hz"),
            "f_truth_hz": truth_frequency(npz, clip.meta["split"]["n_train"]), "s_freq": frequency_scale(mm),
            "zeta_sim": val("zeta_sim"), "zeta_enc": val("zeta_enc"), "zeta_truth": truth_damping(npz, clip), "s_zeta": damping_scale(mm),
            "metrics": mm}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--calibrate", action="store_true", help="calibrate on the calibration half and score the test half")
    ap.add_argument("--runs", type=Path, required=True, help="the realistic suite's run folders (one per clip)")
    ap.add_argument("--clips", type=Path, default=Path("data/cache/realistic"), help="the rendered clips and their truth")
    ap.add_argument("--calibrate-on", choices=("half", "all"), default="half",
                    help="half: the calibration half of --runs (the other half tested); all: every run of --runs (--test-runs tested)")
    ap.add_argument("--test-runs", type=Path, help="with --calibrate-on all: the runs the coverage is measured on")
    ap.add_argument("--out", type=Path, default=REPORTS / "intervals.md")
    ap.add_argument("--calibration", type=Path, default=CALIBRATION_FILE, help="where the constants go")
    args = ap.parse_args()
    if not args.calibrate:
        ap.error("nothing to do: give --calibrate")
    if (args.calibrate_on == "all") != (args.test_runs is not None):
        ap.error("--calibrate-on all and --test-runs go together")
    rep = Report("Interval calibration on the realistic suite (split conformal, 90 %)", args.out, __file__)
    def read(runs: Path) -> list[dict]:
        names = sorted(p.name for p in runs.iterdir() if p.is_dir() and (args.clips / f"{p.name}.truth.npz").exists())
        return [r for r in (row(n, runs, args.clips) for n in names) if r is not None]

    rows = read(args.runs)
    if args.calibrate_on == "all":
        for r in rows:
            r["half"] = "calibration"
        fresh = read(args.test_runs)
        for r in fresh:
            r["half"] = "test"
        rows += fresh
    for r in rows:
        # the interval's own measure: |f_truth - f_sim| in units of its half-width per unit k, s_f f_sim
        r["r_freq"] = abs(r["f_truth_hz"] / r["f_sim_hz"] - 1) / r["s_freq"] if r["f_sim_hz"] and r["s_freq"] else float("nan")
        ok = None not in (r["zeta_sim"], r["zeta_truth"], r["s_zeta"])
        r["r_zeta"] = abs(r["zeta_sim"] - r["zeta_truth"]) / r["s_zeta"] if ok else float("nan")
    cal = [r for r in rows if r["half"] == "calibration"]
    k_f, k_z = conformal_k([r["r_freq"] for r in cal]), conformal_k([r["r_zeta"] for r in cal])
    calibration = {"level": LEVEL, "k_freq": k_f, "k_zeta": k_z, "clips": [r["clip"] for r in cal], "commit": git_commit(),
                   "method": "split conformal, scale = the clip's own disagreement plus a floor (lagsplat.evaluate.intervals)"}  # fmt: skip
    table = []
    for r in rows:
        iv = intervals(r["metrics"], calibration)
        fi, zi = iv["f_sim_hz_interval"]["value"], iv["zeta_sim_interval"]["value"]
        r["f_covered"] = None if fi is None else bool(fi[0] <= r["f_truth_hz"] <= fi[1])
        r["zeta_covered"] = None if zi is None or r["zeta_truth"] is None else bool(zi[0] <= r["zeta_truth"] <= zi[1])
        table.append({"clip": r["clip"], "half": r["half"], "f_truth_hz": round(r["f_truth_hz"], 4), "f_sim_hz": round(r["f_sim_hz"], 4),
                      "f_interval_hz": None if fi is None else f"{fi[0]:.4f}-{fi[1]:.4f}", "f_covered": r["f_covered"],
                      "zeta_truth": None if r["zeta_truth"] is None else round(r["zeta_truth"], 4),
                      "zeta_sim": None if r["zeta_sim"] is None else round(r["zeta_sim"], 4),
                      "zeta_interval": None if zi is None else f"{zi[0]:.4f}-{zi[1]:.4f}", "zeta_covered": r["zeta_covered"]})  # fmt: skip
    summary = []
    for h in ("test", "calibration"):
        for system in sorted({r["system"] for r in rows}) + ["all"]:
            sel = [r for r in rows if r["half"] == h and (system == "all" or r["system"] == system)]
            fc = [r["f_covered"] for r in sel if r["f_covered"] is not None]
            zc = [r["zeta_covered"] for r in sel if r["zeta_covered"] is not None]
            summary.append({"half": h, "system": system, "clips": len(sel), "frequency covered": f"{sum(fc)}/{len(fc)}",
                            "damping covered": f"{sum(zc)}/{len(zc)}"})  # fmt: skip
    rep.text(f"{len(rows)} runs read ({len(cal)} calibrating, {len(rows) - len(cal)} tested; calibrate on: {args.calibrate_on}); "
             f"k_freq = {k_f:.3g}, k_zeta = {k_z:.3g} (the ceil((n+1) 0.9)-th smallest score of the calibration half).")  # fmt: skip
    rep.table(summary, "Coverage of the truth by the 90 % intervals (the test half is the measurement; the calibration half for reference)")
    rep.table(table, "Per clip")
    write_json(args.calibration, calibration)
    rep.text(f"Constants written to `{args.calibration.name}` (lagsplat/evaluate/).")
    rep.write()


if __name__ == "__main__":
    main()
