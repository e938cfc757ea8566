"""Automatic preparation on the realistic suite and its nuisance clips, against the ground truth.

For every rendered clip (``lagsplat.synth.realistic``: the suite, the outside-the-model-class clips and the
nuisance clips, in ``--clips``), run :func:`lagsplat.prepare.prepare_video` as ingest does (source and frame
rate only) and :func:`lagsplat.prepare.auto_split`, and compare the frequency with the truth's observed
frequency (``observed_hz`` where the truth gives it, over the frames where the object moves; otherwise the
paper's spectral estimator on the true ``q`` over the whole clip). ``--compare`` reads the rows of an earlier
run (this script's JSON, or JSON lines with ``name``, ``crop``, ``resize``, ``train_fraction``) and counts the
clips whose crop, working resolution and number of training frames are unchanged.

    python -m lagsplat.synth.realistic --clip NAME --out data/cache/realistic    # or: snakemake -c2 realistic_suite realistic_nuisance
    python benchmarks/prepare_realistic.py --clips data/cache/realistic [--compare OLD.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import Report, add_report_options  # this script's folder

from lagsplat.io.clip import ClipError  # noqa: E402
from lagsplat.prepare import auto_split, prepare_video  # noqa: E402
from lagsplat.synth.realistic import nuisance_clips, outside_class_clips, realistic_suite  # noqa: E402
from lagsplat.timeseries import spectral_peak_frequency  # noqa: E402

FPS = 30.0


def truth_frequency(truth: Path) -> float:
    """The clip's observed frequency (Hz): ``observed_hz`` when the truth file has it, else the spectral peak of the true ``q``."""
    tr = np.load(truth)
    if "observed_hz" in tr.files:
        return float(tr["observed_hz"])
    q = np.asarray(tr["q"], float)
    return spectral_peak_frequency(q[:, 0] if q.ndim == 2 else q, float(np.median(np.diff(tr["t"]))))


def row_of(entry: dict, clips: Path) -> dict:
    """One clip's reading: crop, resize, frequency and its error, split, or the refusal."""
    name = entry["name"]
    mp4, truth = clips / f"{name}.mp4", clips / f"{name}.truth.npz"
    row = {"name": name, "kind": entry.get("nuisance") or entry.get("outside_class") or "suite"}
    if not mp4.exists():
        return {**row, "status": "missing"}
    n = len(np.load(truth)["t"])
    t0 = time.perf_counter()
    try:
        p = prepare_video(mp4, fps=FPS)
        frac, note = auto_split(n, p.frequency_hz, FPS, p.periods, str(mp4))
    except ClipError as exc:
        return {**row, "status": "refused", "note": str(exc).split(": ", 1)[-1][:200], "wall_s": time.perf_counter() - t0}
    f_true = truth_frequency(truth) if not entry.get("outside_class") else float("nan")
    err = abs(p.frequency_hz / f_true - 1) if np.isfinite(f_true) else float("nan")
    return {**row, "status": "prepared", "crop": p.crop, "resize": p.resize, "frequency_hz": p.frequency_hz, "truth_hz": f_true,
            "rel_error": err, "train_fraction": frac, "n_train": int(frac * n), "set_aside": len(p.dropped), "note": note or "",
            "wall_s": time.perf_counter() - t0}  # fmt: skip


def compare(rows: list[dict], old_path: Path) -> tuple[int, int, list[str]]:
    """Clips whose crop, resize and training frames match the earlier run: ``(same, compared, changed names)``."""
    text = old_path.read_text()
    try:
        old = json.loads(text)["rows"]
    except json.JSONDecodeError:  # JSON lines
        old = [json.loads(ln) for ln in text.splitlines() if ln.strip()]
    by_name = {r["name"]: r for r in old}
    same, n, changed = 0, 0, []
    for r in rows:
        o = by_name.get(r["name"])
        if o is None or r["status"] != "prepared" or o.get("crop", "x") == "x" or o.get("train_fraction") is None:
            continue
        n += 1
        n_train_old = o.get("n_train", None)
        if n_train_old is None:
            n_train_old = int(o["train_fraction"] * o.get("n_frames", round(r["n_train"] / r["train_fraction"])))
        if r["crop"] == o["crop"] and r["resize"] == o["resize"] and r["n_train"] == n_train_old:
            same += 1
        else:
            changed.append(r["name"])
    return same, n, changed


def main() -> None:
    """Parse the command line, read every clip, print and write the report."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--clips", type=Path, default=Path("data/cache/realistic"), help="the rendered clips")
    ap.add_argument("--compare", type=Path, help="an earlier run's rows to compare crops, resolutions and splits with")
    report = add_report_options(ap, "prepare_realistic")
    args = ap.parse_args()
    rep = Report("Automatic preparation on the realistic suite and its nuisance clips", args.report, __file__)
    rows = [row_of(e, args.clips) for e in realistic_suite() + outside_class_clips() + nuisance_clips()]
    for kind in ("suite", "nuisance"):
        part = [r for r in rows if (r["kind"] == "suite") == (kind == "suite") and r["kind"] not in ("rotation", "leaves_frame")]
        ok = [r for r in part if r["status"] == "prepared"]
        errs = np.array([r["rel_error"] for r in ok])
        rep.text(f"{kind}: {len(ok)} of {len(part)} prepared; frequency within 5 % of the truth on {(errs <= 0.05).sum()} "
                 f"({np.median(errs) if len(errs) else float('nan'):.2%} median error); identified without held-out frames: "
                 f"{sum(r['train_fraction'] == 1.0 for r in ok)}")  # fmt: skip
    outside = [r for r in rows if r["kind"] in ("rotation", "leaves_frame")]
    rep.text("outside the model class: " + "; ".join(f"{r['name']} {r['status']}" for r in outside))
    if args.compare is not None:
        same, n, changed = compare(rows, args.compare)
        rep.text(f"against {args.compare}: crop, resolution and training frames unchanged on {same} of {n}; changed: {', '.join(changed) or 'none'}")
    rep.table([{k: (round(v, 4) if isinstance(v, float) else v) for k, v in r.items()} for r in rows])
    if args.report is not None:
        rep.write()
        args.report.with_suffix(".json").write_text(json.dumps({"rows": rows}, indent=1, default=float))
    del report


if __name__ == "__main__":
    main()
