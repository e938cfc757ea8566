"""Stage-2 training speed: seconds per optimiser step by inertia form, and per epoch of a new clip's default fit.

Stage 2 (paper §3.3, Eq. 8) trains on windows of the frozen chart; its cost per
step is set by the acceleration of Eq. 7 (the potential's gradient, the
inertia's derivative for the velocity terms) evaluated twice per Verlet step
and differentiated once. This script times, each setting in a fresh process
(one thread):

* ``d1-default``: a d = 1 chart at the defaults of a new clip (learned ``M(q)``,
  four chained steps per window), one optimiser step at batch 32;
* ``d1-paper``: the paper's d = 1 fit (scalar mass, one step);
* ``d4-learned`` / ``d4-constant`` / ``d4-decoder``: the soft-robot operating
  point (d = 4, four pressures, one step) with learned, constant and
  decoder-induced inertia (2048 Gaussians);
* ``d1-epochs``: :func:`~lagsplat.train.stage2.train_stage2` on a simulated
  damped oscillator at the defaults, seconds per epoch (1000 windows and the
  selection rollouts).

``--against COMMIT`` times the same settings on another commit (a git worktree)
in alternating rounds and prints the speed-up as a ratio of the two, measured
in one run.

Usage::

    python benchmarks/stage2.py [--settings ...] [--against COMMIT] [--rounds 2]

Prints figures and writes them to ``results/benchmarks/stage2.md``
(``--report PATH``, ``--no-report``); asserts nothing.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent

#: Setting -> (latent dimension, inertia form, chained steps, actuation channels); ``d1-epochs`` is a whole fit.
SETTINGS: dict[str, tuple[int, str, int, int]] = {
    "d1-default": (1, "learned", 4, 0),
    "d1-paper": (1, "scalar", 1, 0),
    "d4-learned": (4, "learned", 1, 4),
    "d4-constant": (4, "constant", 1, 4),
    "d4-decoder": (4, "decoder", 1, 4),
    "d1-epochs": (1, "learned", 4, 0),
}


def _step_seconds(d: int, mass: str, K: int, n_u: int, steps: int) -> float:
    """Median seconds of one Adam step on random windows at batch 32 (after warm-up steps)."""
    import math

    import torch
    from _common import time_call

    from lagsplat.train.shooting import shooting_loss
    from lagsplat.train.stage2 import Stage2Config

    torch.manual_seed(0)
    inertia = None
    if mass == "decoder":
        from lagsplat.models.decoder import ConditionedGaussians
        from lagsplat.models.inertia import DecoderInertia

        dec = ConditionedGaussians(2048, d)
        dec.init_from_frame(torch.rand(3, 32, 32), torch.randn(64, d))
        inertia = DecoderInertia.from_decoder(dec, torch.eye(d), torch.zeros(d), 32, 32)
    cfg = Stage2Config(mass=mass, rollout_steps=K)
    model = cfg.build(d, n_u, inertia)
    model.init_energy_scales(2 * math.pi * 1.5, 0.01)
    model.train()
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    B = 32
    q0, v0 = torch.randn(B, d), torch.randn(B, d)
    Q, V, U = torch.randn(B, K, d), torch.randn(B, K, d), torch.rand(B, K + 1, n_u)
    A = torch.eye(d)

    def step() -> None:
        loss = shooting_loss(model, q0, v0, Q, V, U, 2 / 60, A, 0.1, 0.1)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()

    for _ in range(4):  # Adam's state and the allocator settle (time_call warms up once more)
        step()
    return time_call(step, steps)


def _epoch_seconds(epochs: int) -> float:
    """Seconds per epoch of the default Stage-2 fit of a simulated damped oscillator (30 fps, 20 s, 60 % training)."""
    import math
    import time

    import numpy as np

    from lagsplat.chart import Chart
    from lagsplat.io.clip import TRAIN
    from lagsplat.train.stage2 import Stage2Config, train_stage2

    dt, n = 1 / 30, 600
    t = np.arange(n) * dt
    x = np.exp(-0.05 * t) * np.cos(2 * math.pi * 0.8 * t)
    q = (x / x.std() + 0.01 * np.random.default_rng(0).standard_normal(n))[:, None]
    split = np.full(n, TRAIN, np.int8)
    split[int(0.6 * n) :] = 1
    eye = np.eye(1)
    chart = Chart(mean=np.zeros(1), W=eye, W_inv=eye, q=q, t=t, split=split, G_bar=eye, A=eye, ae_mse=np.zeros(n),
                  ae_floor_train=0.0, ae_floor_held_out=0.0, height=64, width=64)  # fmt: skip
    t0 = time.perf_counter()
    train_stage2(chart, Stage2Config(epochs=epochs, select_every=1), progress=False)
    return (time.perf_counter() - t0) / epochs


def worker(setting: str, steps: int) -> dict:
    """One setting's timing in this process (one thread)."""
    import torch

    torch.set_num_threads(1)
    if setting == "d1-epochs":
        return {"seconds": _epoch_seconds(max(2, steps // 10))}
    return {"seconds": _step_seconds(*SETTINGS[setting], steps)}


def _run(root: Path, setting: str, steps: int) -> float:
    """``worker(setting)`` in a fresh process importing ``lagsplat`` from ``root``."""
    env = {**os.environ, "PYTHONPATH": str(root), "OMP_NUM_THREADS": "1"}
    out = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--worker", setting, "--steps", str(steps)],
                         env=env, capture_output=True, text=True, check=True)  # fmt: skip
    return float(json.loads(out.stdout.strip().splitlines()[-1])["seconds"])


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--settings", nargs="+", default=list(SETTINGS), choices=list(SETTINGS))
    ap.add_argument("--steps", type=int, default=40, help="timed optimiser steps per setting (d1-epochs: a tenth as epochs, at least 2)")
    sys.path.insert(0, str(HERE))
    from _common import Report, add_comparison_options, add_report_options, against_columns, alternating_medians, checkouts

    add_comparison_options(ap)
    add_report_options(ap, "stage2")
    args = ap.parse_args(argv)
    if args.worker:
        print(json.dumps(worker(args.worker, args.steps)))
        return

    rep = Report("Stage-2 training speed", args.report, __file__, argv)
    rep.text(f"seconds per optimiser step at batch 32 (median of {args.steps} steps), or per epoch for d1-epochs; each setting in a fresh "
             f"process, one thread, median of {args.rounds} round(s)")  # fmt: skip
    with checkouts(args.against) as roots:
        rows = []
        for setting in args.settings:
            medians = alternating_medians(roots, args.rounds, lambda root: _run(root, setting, args.steps))
            d, mass, K, n_u = SETTINGS[setting]
            unit = "s/epoch" if setting == "d1-epochs" else "s/step"
            row = {"setting": setting, "d": d, "inertia": mass, "steps/window": K, "pressures": n_u,
                   unit: f"{medians['this checkout']:.4f}", **against_columns(medians, unit)}  # fmt: skip
            rows.append(row)
            print(f"  done: {row}", flush=True)
        rep.table(rows)
        rep.write()

if __name__ == "__main__":
    main()
