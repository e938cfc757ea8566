"""Projected wall time of a Snakemake run, printed before its first job starts: the soft-robot chain, and the
paper target item by item (:func:`project_items`, workflow/rules/paper.smk).

The projection is a cost model: each planned job's budget (Stage-1 steps, Stage-2 optimiser steps, frames
encoded or rolled out) times a per-unit cost measured on the reference machine (:data:`COSTS`: 2 CPU cores,
one thread per job, as ``snakemake -c2`` runs two jobs side by side). Jobs of different robots run in
parallel up to the cores given; the chain of one robot runs in order. The download is not projected (it
depends on the network). A machine other than the reference one scales every number by about the same factor.
Rules the cost model does not price (the extrapolation baselines, the diagnosis, the figures, the views) are
counted and named, never guessed.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np

__all__ = ["COSTS", "REAL_FRAMES", "PRICED_RULES", "job_seconds", "project", "projection_lines", "project_items", "item_lines"]

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


def _video_frames(path: Path, cfg: Any) -> int | None:
    """Frames of a video on disk inside the system's ``frames: [start, stop]`` range (OpenCV's count), or ``None``."""
    try:
        import cv2
    except ImportError:
        return None
    cap = cv2.VideoCapture(str(path))
    n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) if cap.isOpened() else 0
    cap.release()
    if n <= 0:
        return None
    start, stop = (list(cfg.system.get("frames") or []) + [None, None])[:2]
    return max(0, min(n, n if stop is None else int(stop)) - int(start or 0))


def _frames(cfg: Any) -> int | None:
    """Frames of the system's clip: the NPZ's or the video's when it is on disk, else the generator's length (a
    surrogate, a procedural clip), else the released recording's; ``None`` when none of these says."""
    src = cfg.system.source
    path = Path(str(src.get("path") or ""))
    if path.is_file() and path.suffix == ".npz":
        with np.load(path, mmap_mode="r", allow_pickle=False) as z:
            key = "images" if "images" in z.files else z.files[0]
            return int(z[key].shape[0])
    if path.is_file():
        n = _video_frames(path, cfg)
        if n is not None:
            return n
    gen = src.get("generator") or src.get("params")
    if gen is not None and gen.get("duration_s") is not None:
        rate = float(gen.fps) if gen.get("fps") is not None else 1.0 / float(src.dt)
        return int(round(float(gen.duration_s) * rate))
    return REAL_FRAMES.get(str(cfg.system.name))


def job_seconds(rule: str, cfg: Any) -> float:
    """Projected seconds of one job ``rule`` run with the composed configuration ``cfg`` (its system's, with a
    variant's settings merged in for ``stage2_variant`` / ``evaluate_variant``). Rules outside the chain (and
    the download) cost 0 (:data:`PRICED_RULES` are the others); a clip of unknown length costs its per-frame jobs 0."""
    T = _frames(cfg) or 0
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
    if rule == "seed_run":  # python -m lagsplat all: the chain in one process (its rollout figure is not priced)
        return sum(job_seconds(r, cfg) for r in ("ingest", "stage1", "chart", "stage2", "evaluate"))
    if rule == "deformation_table":  # the deformation decoder's Stage 1 at the run's budget (the comparison itself is not priced)
        return job_seconds("stage1", cfg)
    return 0.0


PRICED_RULES = frozenset({"stage1", "chart", "stage2", "stage2_variant", "evaluate", "evaluate_variant", "ingest", "krauss_extract",
                          "krauss_synth", "robot_figures", "seed_run", "deformation_table"})  # fmt: skip
"""The rules :func:`job_seconds` prices; every other rule's jobs are counted as not projected."""


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


def project_items(items: Mapping[str, list[tuple[str, str, Any, int]]], cores: int) -> dict[str, Any]:
    """Projected wall time of the paper target (workflow/rules/paper.smk), item by item.

    Args:
        items: item -> its planned jobs ``(rule, lane, cfg, threads)``, each job under the first item that needs it;
            ``lane`` groups the jobs that run in order (one system's chain, one seed's run), ``cfg`` the job's
            composed configuration (``None``: a job with no system of its own, a table), ``threads`` its rule's.
        cores: cores the run may use.

    Returns:
        ``{"items": {item: seconds}, "unpriced": {rule: jobs}, "job_seconds", "wall_seconds", "cores"}``: the wall
        time is the longer of the priced work spread over the cores (a job holding as many cores as its threads)
        and the longest lane; the jobs of :data:`PRICED_RULES`' complement count in ``unpriced``, not in the time.
    """
    cores = max(1, int(cores))
    per: dict[str, float] = {}
    lanes: dict[str, float] = {}
    unpriced: dict[str, int] = {}
    work = 0.0
    for item, jobs in items.items():
        per[item] = 0.0
        for rule, lane, cfg, threads in jobs:
            if rule not in PRICED_RULES or cfg is None:
                unpriced[rule] = unpriced.get(rule, 0) + 1
                continue
            s = job_seconds(rule, cfg)
            per[item] += s
            lanes[lane] = lanes.get(lane, 0.0) + s
            work += s * min(max(1, int(threads)), cores)
    total = sum(per.values())
    return {"items": per, "unpriced": unpriced, "job_seconds": total, "wall_seconds": max(work / cores, max(lanes.values(), default=0.0)), "cores": cores}


def item_lines(p: dict[str, Any]) -> list[str]:
    """The projection :func:`project_items` returns, as the lines printed before the paper target's first job."""
    lines = [f"[lagsplat] projected wall time of the paper target on {p['cores']} core(s): at least {_hms(p['wall_seconds'])} "
             f"({_hms(p['job_seconds'])} of priced jobs; per-step costs of a 2-core reference machine)"]  # fmt: skip
    lines += [f"[lagsplat]   {k}: {_hms(v) if v > 0 else 'nothing priced'}" for k, v in p["items"].items()]
    if p["unpriced"]:
        named = ", ".join(f"{r} x{n}" for r, n in sorted(p["unpriced"].items()))
        lines.append(f"[lagsplat]   not in the cost model, so not in the time above: {named}")
    return lines
