"""Projected wall time of a Snakemake run of the soft-robot chain, printed before its first job starts.

The projection is a cost model: each planned job's budget (Stage-1 steps, Stage-2 optimiser steps, frames
encoded or rolled out) times a per-unit cost measured on the reference machine (:data:`COSTS`: 2 CPU cores,
one thread per job, as ``snakemake -c2`` runs two jobs side by side). Jobs of different robots run in
parallel up to the cores given; the chain of one robot runs in order. The download is not projected (it
depends on the network). A machine other than the reference one scales every number by about the same factor.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Iterable

import numpy as np

__all__ = ["COSTS", "REAL_FRAMES", "job_seconds", "project", "projection_lines"]

#: Per-unit costs (seconds) on the reference machine, one thread per job: measured from the stage timings
#: of ``snakemake -c2 krauss --config krauss_source=synthetic`` (two-segment surrogate, 300 s = 17 982 frames);
#: the Stage-2 steps as the slope between 2 and 8 epochs of 3000 windows of each inertia's variant on its frozen chart.
COSTS: dict[str, float] = {
    "stage1_step": 0.100,  # per Stage-1 optimiser step at batch 16 with 2048 Gaussians on 32x32 frames
    "chart_frame": 4.7e-3,  # per frame encoded and scored by the chart (whitening, G_bar, AE floor)
    "stage2_step_learned": 0.020,  # per Stage-2 optimiser step (32 windows), learned M(q), selection rollouts included
    "stage2_step_constant": 0.020,
    "stage2_step_scalar": 0.015,
    "stage2_step_decoder": 0.048,  # decoder-induced inertia (paper Eq. 7): its sum over the 2048 primitives and dM/dq at every step
    "evaluate_frame": 3.0e-4,  # published protocol: 50 windows, frequency and AE-floor passes over the validation clip
    "ingest_frame": 7e-5,
    "robot_figures": 20.0,  # per robot: the two figures
}

#: Frames of the released recordings (paper §4.4: 80 % train = 43 872 and 43 800 frames).
REAL_FRAMES: dict[str, int] = {"krauss_2seg": 54_840, "krauss_1seg": 54_750}


def _frames(cfg: Any) -> int:
    """Frames of the system's clip: the NPZ's when it is on disk, else the released recording's or the surrogate's length."""
    src = cfg.system.source
    path = Path(str(src.get("path") or ""))
    if path.is_file() and path.suffix == ".npz":
        with np.load(path, mmap_mode="r", allow_pickle=False) as z:
            key = "images" if "images" in z.files else z.files[0]
            return int(z[key].shape[0])
    gen = src.get("generator")
    if gen is not None:
        return int(round(float(gen.duration_s) / float(src.dt)))
    return REAL_FRAMES.get(str(cfg.system.name), 54_840)


def job_seconds(rule: str, cfg: Any) -> float:
    """Projected seconds of one job ``rule`` run with the composed configuration ``cfg`` (its system's, with a
    variant's settings merged in for ``stage2_variant`` / ``evaluate_variant``). Rules outside the chain (and
    the download) cost 0."""
    T = _frames(cfg)
    s1, s2 = cfg.stage1, cfg.stage2
    if rule == "stage1":
        scale = (float(s1.batch) / 16.0) * (0.5 + 0.5 * float(s1.n_gaussians) / 2048.0)
        return float(s1.steps) * COSTS["stage1_step"] * scale
    if rule == "chart":
        return T * COSTS["chart_frame"]
    if rule in ("stage2", "stage2_variant"):
        mass = str(s2.mass)
        steps = int(s2.epochs) * math.ceil(int(s2.windows_per_epoch) / int(s2.batch))
        return steps * COSTS.get(f"stage2_step_{mass}", COSTS["stage2_step_learned"])
    if rule in ("evaluate", "evaluate_variant"):
        return T * COSTS["evaluate_frame"]
    if rule in ("ingest", "krauss_extract", "krauss_synth"):
        return T * COSTS["ingest_frame"]
    if rule == "robot_figures":
        return COSTS["robot_figures"]
    return 0.0


def project(jobs: Iterable[tuple[str, str, Any]], cores: int) -> dict[str, Any]:
    """Projected wall time of the planned ``jobs`` on ``cores`` cores.

    Args:
        jobs: ``(rule, system, cfg)`` per job, ``cfg`` the composed configuration the job runs with
            (a variant's merged in).
        cores: cores the run may use. Each system's jobs run in order; different systems share the cores
            (the longest chain first onto the least loaded core).

    Returns:
        ``{"systems": {system: seconds}, "job_seconds": total, "wall_seconds": projection, "cores": cores}``.
    """
    per: dict[str, float] = {}
    for rule, system, cfg in jobs:
        per[system] = per.get(system, 0.0) + job_seconds(rule, cfg)
    total = sum(per.values())
    lanes = [0.0] * max(1, int(cores))
    for s in sorted(per.values(), reverse=True):
        lanes[int(np.argmin(lanes))] += s
    return {"systems": per, "job_seconds": total, "wall_seconds": max(lanes) if per else 0.0, "cores": max(1, int(cores))}


def _hms(s: float) -> str:
    return f"{int(s // 3600)} h {int(s % 3600 // 60):02d} min" if s >= 3600 else f"{max(1, round(s / 60))} min"


def projection_lines(p: dict[str, Any]) -> list[str]:
    """The projection :func:`project` returns, as the lines printed before the run."""
    if not p["systems"]:
        return []
    lines = [f"[lagsplat] projected wall time of the soft-robot jobs on {p['cores']} core(s): about {_hms(p['wall_seconds'])} "
             f"({_hms(p['job_seconds'])} of jobs; per-step costs of a 2-core reference machine, downloads not included)"]  # fmt: skip
    lines += [f"[lagsplat]   {s}: {_hms(v)}" for s, v in sorted(p["systems"].items())]
    return lines
