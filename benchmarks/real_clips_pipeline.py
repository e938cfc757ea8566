"""The whole pipeline on the real-clip set, configured with source, frames and frame rate only, against the references.

``--run`` runs ``python -m lagsplat all`` and then ``diagnose`` on each clip of the chosen split (the
``realistic`` system configuration: region of interest, resolution and split automatic), writing under
``--results``; ``--gather`` reads each run's ``metrics.json`` (the identified frequency ``f_sim_hz``: held out,
or in-sample for a clip too short for held-out frames), ``stage1.pt``'s attempts, the stop record and the
diagnosis, and compares ``f_sim_hz`` with the manifest's independent reference
(``results/benchmarks/real_clips_pipeline_<split>.md``).

    python benchmarks/real_clips_pipeline.py --run --split test --results /scratch/real
    python benchmarks/real_clips_pipeline.py --gather --split test --results /scratch/real
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import REPORTS, Report  # this script's folder
from real_clips import PASS_TOL, clip_path, load_manifest  # this script's folder

ROOT = Path(__file__).resolve().parents[1]


def overrides(entry: dict, results: Path) -> list[str]:
    """The command line's settings for one clip: its source, frame rate and frame range, nothing tuned."""
    start, stop = entry["frames"]
    return ["system=realistic", f"system.name=real_{entry['name']}", f"system.title={entry['name']}", f"system.source.path={clip_path(entry)}",
            f"system.source.fps={entry['fps']}", f"+system.frames=[{start or 0},{'null' if stop is None else stop}]",
            f"results_dir={results}", "progress=false", "system.data=real",
            f"system.provenance='{entry['source_repo']} {entry['source_path']} @ {entry['source_commit'][:10]}, {entry['licence'].split(' (')[0]}'"]  # fmt: skip


def run(entry: dict, results: Path, threads: int) -> None:
    """``all`` then ``diagnose`` on one clip; their output goes to ``<results>/real_<name>.log``."""
    log = results / f"real_{entry['name']}.log"
    results.mkdir(parents=True, exist_ok=True)
    with open(log, "w") as fh:
        for stage in ("all", "diagnose"):
            t0 = time.perf_counter()
            r = subprocess.run([sys.executable, "-m", "lagsplat", stage, *overrides(entry, results), f"threads={threads}"], cwd=ROOT, stdout=fh, stderr=subprocess.STDOUT)
            fh.write(f"[real_clips_pipeline] {stage}: exit {r.returncode} in {time.perf_counter() - t0:.0f} s\n")
    print(f"{entry['name']}: done ({log})", flush=True)


def gather_row(entry: dict, results: Path) -> dict:
    """One clip's row: identified frequency against the reference, Stage-1 attempts, the stop or the diagnosis."""
    d = results / f"real_{entry['name']}"
    row = {"clip": entry["name"], "nuisances": ", ".join(entry.get("nuisances", [])), "reference_hz": entry["reference_hz"]}
    if (d / "stopped.json").exists():
        stop = json.loads((d / "stopped.json").read_text())
        row.update(status=f"stopped at {stop.get('stage')}", note=str(stop.get("reason"))[:200])
    mpath = d / "metrics.json"
    if mpath.exists():
        m = json.loads(mpath.read_text())
        f = (m.get("metrics", {}).get("f_sim_hz") or {}).get("value")
        row["f_sim_hz"] = f
        row["held_out"] = m.get("held_out") or "held out"
        if f is not None:
            err = abs(f / entry["reference_hz"] - 1)
            row.update(rel_error=round(err, 4), status="pass" if err <= PASS_TOL else "fail")
    try:
        import torch

        hist = torch.load(d / "stage1.pt", map_location="cpu", weights_only=False).get("history", {})
        row["stage1_attempts"] = len(hist.get("attempts", [])) or 1
    except (OSError, RuntimeError, AttributeError):
        pass
    rep = d / "diagnosis" / "report.json"
    if rep.exists():
        row["diagnosis"] = json.loads(rep.read_text()).get("verdict")
    row.setdefault("status", "not run")
    return row


def main() -> None:
    """Parse the command line; run or gather."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    job = ap.add_mutually_exclusive_group(required=True)
    job.add_argument("--run", action="store_true")
    job.add_argument("--gather", action="store_true")
    ap.add_argument("--split", choices=["test", "tune", "all"], default="test")
    ap.add_argument("--only", nargs="*", default=None, help="clip names (default: all of the split)")
    ap.add_argument("--results", type=Path, required=True, help="where the runs' artifacts go")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--no-report", action="store_true")
    args = ap.parse_args()
    entries = [e for e in load_manifest() if (e["name"] in args.only if args.only else args.split in ("all", e["split"]))]
    if args.run:
        for e in entries:
            run(e, args.results, args.threads)
        return
    report = None if args.no_report else REPORTS / f"real_clips_pipeline_{args.split}.md"
    rep = Report(f"The pipeline on the real clips ({args.split} split), source, frames and frame rate only", report, __file__)
    rows = [gather_row(e, args.results) for e in entries]
    ran = [r for r in rows if r["status"] != "not run"]
    rep.text(f"identified frequency within {PASS_TOL:.0%} of the reference: {sum(r['status'] == 'pass' for r in ran)} of {len(ran)} clips run "
             f"({len(rows) - len(ran)} of the split not run)")  # fmt: skip
    rep.table(rows)
    if report is not None:
        rep.write()


if __name__ == "__main__":
    main()
