"""Training throughput at the soft-robot operating point, and the wall time it projects for the real data.

Is the full 43 872-frame Krauss benchmark practical on one
CPU machine? This script measures, on a short simulated two-segment robot in
the identical format (``lagsplat.synth.continuum_robot``; 32x32 RGB, 4
pressures, d = 4, 2048 Gaussians):

* Stage 1 (encoder + conditioned-Gaussian decoder, CPU tile rasteriser, the
  batch rendered in parallel over (image, tile) pairs): optimiser steps per
  second and frames per second at batch 16 and 64;
* Stage 2 (one-step velocity-Verlet windows, learned M(q), invex potential,
  pressure forcing): optimiser steps per second and windows per second at
  batch 32;

each as the slope between a short and a longer run (so set-up, compilation
and the chart are not counted), and projects the wall time of

* the published budget (the reference code): Stage 1 68.6k steps x 64 frames,
  Stage 2 47k steps x 32 windows;
* the suggested override of ``conf/system/krauss_2seg.yaml`` (Stage 1 50k x 64, Stage 2 500 x 3000 windows).

Usage::

    python benchmarks/krauss_throughput.py [--threads 2]

Prints figures and writes them to ``results/benchmarks/krauss_throughput.md``
(``--report PATH``, ``--no-report``); asserts nothing. The load average is
printed: on a shared machine the rates are lower bounds.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _common import Report, add_report_options, env_header

import lagsplat  # noqa: F401,E402  (OpenMP wait policy before torch)


def _timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--seconds", type=float, default=40.0, help="length of the simulated clip")
    ap.add_argument("--steps", type=int, default=90, help="Stage-1 steps of the longer run (the short one has a third)")
    add_report_options(ap, "krauss_throughput")
    args = ap.parse_args(argv)

    import torch

    from lagsplat.chart import build_chart
    from lagsplat.io.npz import read_npz
    from lagsplat.synth.continuum_robot import write_robot_npz
    from lagsplat.train.stage1 import Stage1Config, train_stage1
    from lagsplat.train.stage2 import Stage2Config, train_stage2

    torch.set_num_threads(args.threads)
    rep = Report("Training throughput at the soft-robot operating point", args.report, __file__, argv)
    print(env_header("numba CPU rasteriser"), f"; load average {os.getloadavg()[0]:.2f}")
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "robot.npz"
        write_robot_npz(path, 2, duration_s=args.seconds, seed=0)
        clip = _clip(read_npz, path)
    rep.text(f"clip: simulated two-segment robot, {len(clip.images)} frames {clip.images.shape[1:3]}, {clip.u.shape[1]} pressures, d = 4, 2048 Gaussians")

    rows = []
    ae = None
    # warm-up: numba loads (or compiles) the rasteriser's kernels on the first call of the process
    train_stage1(clip, Stage1Config(n_gaussians=2048, steps=2, batch=16), d=4, seed=0, progress=False)
    for batch in (16, 64):
        n_long, n_short = args.steps, max(1, args.steps // 3)
        cfg = lambda n: Stage1Config(n_gaussians=2048, steps=n, batch=batch, recycle_warmup=10**9)  # noqa: E731
        t_short = _timed(lambda: train_stage1(clip, cfg(n_short), d=4, seed=0, progress=False))
        out = {}
        t_long = _timed(lambda: out.setdefault("ae", train_stage1(clip, cfg(n_long), d=4, seed=0, progress=False)[0]))
        ae = out["ae"]
        per_step = (t_long - t_short) / (n_long - n_short)
        rows.append({"stage": "1", "batch": batch, "s/step": per_step, "steps/s": 1 / per_step, "items/s": batch / per_step, "items": "frames"})

    chart = build_chart(ae, clip, 16, 0.01, 0)
    base = dict(mass="learned", potential="invex", batch=32, windows_per_epoch=320, select_every=10**6, stride=2)
    t1 = _timed(lambda: train_stage2(chart, Stage2Config(epochs=1, **base), seed=0, progress=False))
    t3 = _timed(lambda: train_stage2(chart, Stage2Config(epochs=3, **base), seed=0, progress=False))
    steps = 2 * base["windows_per_epoch"] / base["batch"]
    per_step = (t3 - t1) / steps
    rows.append({"stage": "2", "batch": 32, "s/step": per_step, "steps/s": 1 / per_step, "items/s": 32 / per_step, "items": "windows"})
    table = rep.table(rows)

    s1_64 = float(table[(table.stage == "1") & (table.batch == 64)]["s/step"].iloc[0])
    s2 = float(table[table.stage == "2"]["s/step"].iloc[0])
    proj = [
        {"budget": "published (68.6k x 64 frames; 47k x 32 windows)", "stage 1 h": 68_600 * s1_64 / 3600, "stage 2 h": 47_000 * s2 / 3600},
        {"budget": "suggested override (50k x 64; 500 x 3000 windows / 32)", "stage 1 h": 50_000 * s1_64 / 3600, "stage 2 h": 500 * 3000 / 32 * s2 / 3600},
    ]
    for p in proj:
        p["total h"] = p["stage 1 h"] + p["stage 2 h"]
    rep.table(proj, title="projected wall time on this machine for the real 2-segment data (43 872 training frames):")
    rep.write()


def _clip(read_npz, path):
    """The NPZ as a :class:`~lagsplat.io.clip.Clip` with a contiguous 80/20 split (pressures as actuation)."""
    import numpy as np

    from lagsplat.io.clip import HELD_OUT, TRAIN, Clip

    images, t, u, names, _ = read_npz(path, dt=1001 / 60000)
    split = np.full(len(images), HELD_OUT, np.int8)
    split[: int(0.8 * len(images))] = TRAIN
    return Clip(images=images, t=t, u=u, u_names=list(names), split=split, meta={}).validate(str(path))


if __name__ == "__main__":
    main()
