"""Throughput of rollouts of the latent Lagrangian, free and pressure-driven (steps per second, batch 1).

Paths: ``torch`` (:func:`lagsplat.dynamics.integrators.rollout` with
``fast=False``: autograd ``dV/dq`` at every force evaluation) and ``fast``
(the compiled numba kernels of :mod:`lagsplat.dynamics.fast`, the default for
models in eval mode: scalar, constant or learned inertia, with or without
actuation). Both integrate the same velocity-Verlet scheme (paper Eq. 8).

Models are untrained :class:`~lagsplat.models.lagrangian.Lagrangian` s with the
paper's widths (ICNN / dissipation MLP ``--hidden``, default 64 64; i-ResNet 2
blocks of width 64 for ``--potential invex``), float32, ``init_energy_scales(2 pi,
0.01)`` (1 Hz, floor damping ratio 1 %), released from 1 unit off the rest state.

Rows (``--configs``, ``d:mass:n_u``): actuated rows are driven by a zero-order-hold pressure per step
(a slow sine per channel, in [0, 1]), as the soft-robot protocol rolls out (paper §4.4).

Also times two long rollouts on the compiled path: ``--seconds`` (1000 s) at ``--rate`` (30 Hz) at
d = 1, free; and the same length at ``--robot-rate`` (59.94 Hz) of the soft robot's model form,
d = 4, learned inertia, 4 pressure channels. numba's compilation is timed
separately (a first 1-step call; ``--warm-cache`` keeps numba's on-disk cache,
otherwise a fresh temporary cache directory forces a real compilation), then
the export of the weights (first :func:`~lagsplat.dynamics.fast.cached_export`),
then the first full rollout.

Usage::

    python benchmarks/rollout.py [--configs 1:scalar:0 4:learned:4] [--threads 2] [--repeats 3]

Steps per second are ``steps / median time`` over ``--repeats`` calls after one
warm-up call. Writes what it prints to ``results/benchmarks/rollout.md``
(``--report PATH``, ``--no-report``).
"""

from __future__ import annotations

import argparse
import atexit
import math
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout without installing
# this script's folder; imports nothing heavy (torch and numba are imported in main)
from _common import Report, add_report_options, env_header, time_call


def _parse(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--configs", nargs="+", default=["1:scalar:0", "2:constant:0", "4:constant:0", "4:learned:0", "4:learned:4"],
                    help="rows as d:mass:n_u (latent dimension, inertia, actuation channels)")
    ap.add_argument("--potential", default="convex", choices=["convex", "invex"])
    ap.add_argument("--hidden", type=int, nargs="+", default=[64, 64], help="ICNN / dissipation widths")
    ap.add_argument("--torch-steps", type=int, default=200, help="steps per timed torch rollout")
    ap.add_argument("--fast-steps", type=int, default=30_000, help="steps per timed compiled rollout")
    ap.add_argument("--repeats", type=int, default=3, help="timed calls per configuration (median reported)")
    ap.add_argument("--threads", type=int, default=2, help="torch threads")
    ap.add_argument("--seconds", type=float, default=1000.0, help="length of the long rollout (s)")
    ap.add_argument("--rate", type=float, default=30.0, help="frame rate of the long free rollout (Hz)")
    ap.add_argument("--robot-rate", type=float, default=59.94, help="frame rate of the long actuated rollout (Hz; the soft robot's camera)")
    ap.add_argument("--warm-cache", action="store_true", help="keep numba's on-disk cache (compile time = cache load)")
    add_report_options(ap, "rollout")
    return ap.parse_args(argv)


def main(argv: list[str] | None = None):
    args = _parse(argv)
    if not args.warm_cache:  # before numba is imported: a fresh cache directory, so the first call compiles
        cache_dir = tempfile.mkdtemp(prefix="lagsplat-numba-")
        atexit.register(shutil.rmtree, cache_dir, ignore_errors=True)
        os.environ["NUMBA_CACHE_DIR"] = cache_dir

    import lagsplat  # noqa: F401, I001  (first: sets GOMP_SPINCOUNT before torch starts its threads)
    import numpy as np
    import torch

    from lagsplat.dynamics.integrators import rollout
    from lagsplat.models.lagrangian import Lagrangian

    torch.set_num_threads(args.threads)

    def make(d: int, mass: str = "scalar", n_u: int = 0) -> Lagrangian:
        torch.manual_seed(0)
        model = Lagrangian(d, mass=mass, hidden=tuple(args.hidden), potential=args.potential, n_u=n_u).eval()
        model.init_energy_scales(2 * math.pi, 0.01)
        return model

    def pressures(n_u: int, n_steps: int, rate: float):
        """Zero-order-hold pressures ``[1, n_steps, n_u]`` (slow sines in [0, 1]), or ``None``."""
        if not n_u:
            return None
        t = torch.arange(n_steps, dtype=torch.float64)[:, None] / rate
        f = 0.1 * (1 + torch.arange(n_u, dtype=torch.float64))[None]
        return (0.5 + 0.5 * torch.sin(2 * math.pi * f * t))[None].numpy()

    def state(model: Lagrangian):
        q0 = model.q_rest.detach()[None] + 1.0
        return q0, torch.zeros_like(q0)

    import numba

    rep = Report("Rollout throughput (steps/s, batch 1)", args.report, __file__, argv)
    print(env_header(f"numba {numba.__version__}"))
    rep.text(f"batch 1, h = 1/{args.rate:g} s, widths {tuple(args.hidden)}, potential {args.potential}; median of {args.repeats} timed calls after one warm-up")

    # ---- the long rollout at d = 1, compile time apart
    h = 1.0 / args.rate
    n_long = round(args.seconds * args.rate) + 1
    model = make(1)
    q0, v0 = state(model)
    from lagsplat.dynamics import fast as fast_mod

    t0 = time.perf_counter()  # the export itself runs two of the kernels: compile time includes it
    fast_mod.fast_rollout(fast_mod.export_model(model), q0.numpy(), v0.numpy(), h, 2)
    t_compile = time.perf_counter() - t0
    t0 = time.perf_counter()
    fast_mod.cached_export(model)
    t_export = time.perf_counter() - t0
    t0 = time.perf_counter()
    q, _ = rollout(model, q0, v0, h, n_long)
    t_long = time.perf_counter() - t0
    assert torch.isfinite(q).all()
    # the soft robot's model form: d = 4, learned M(q), four pressure channels, zero-order hold
    robot = make(4, "learned", 4)
    n_robot = round(args.seconds * args.robot_rate) + 1
    P = pressures(4, n_robot - 1, args.robot_rate)
    q0r, v0r = state(robot)
    fm = fast_mod.cached_export(robot)
    fast_mod.fast_rollout(fm, q0r.numpy(), v0r.numpy(), 1.0 / args.robot_rate, 2, u=P[:, :1])  # compile this model form
    t0 = time.perf_counter()
    qr, _ = fast_mod.fast_rollout(fm, q0r.numpy(), v0r.numpy(), 1.0 / args.robot_rate, n_robot, u=P)
    t_robot = time.perf_counter() - t0
    assert np.isfinite(qr).all()
    rep.text(
        f"numba compilation ({'cache load' if args.warm_cache else 'fresh cache'}): {t_compile:.2f} s; weight export: {t_export * 1e3:.1f} ms",
        f"{args.seconds:g} s free rollout at {args.rate:g} Hz, d = 1 ({n_long - 1} steps), compiled path, first call: {t_long:.3f} s",
        f"{args.seconds:g} s actuated rollout at {args.robot_rate:g} Hz, d = 4, learned inertia, 4 pressure channels (zero-order hold; "
        f"{n_robot - 1} steps), compiled path: {t_robot:.3f} s",
    )

    rows = []
    for spec in args.configs:
        d_s, mass, n_u_s = spec.split(":")
        d, n_u = int(d_s), int(n_u_s)
        model = make(d, mass, n_u)
        q0, v0 = state(model)
        P = pressures(n_u, max(args.torch_steps, args.fast_steps), args.rate)
        u_torch = None if P is None else torch.as_tensor(P[:, : args.torch_steps], dtype=torch.float32)
        sched = None if P is None else (lambda t, U=u_torch: U[:, min(int(round(t / h)), U.shape[1] - 1)])  # noqa: E731
        t_torch = time_call(lambda m=model, q=q0, v=v0, u=sched: rollout(m, q, v, h, args.torch_steps + 1, u=u, fast=False), args.repeats)
        t_fast = time_call(lambda m=model, q=q0, v=v0, u=sched: rollout(m, q, v, h, args.fast_steps + 1, u=u, fast=True), args.repeats)
        sps_torch, sps_fast = args.torch_steps / t_torch, args.fast_steps / t_fast
        row = {
            "d": d,
            "mass": model.mass_kind,
            "actuation channels": n_u,
            "torch steps/s": f"{sps_torch:.0f}",
            "fast steps/s": f"{sps_fast:.0f}",
            "speed-up": f"{sps_fast / sps_torch:.0f}x",
            f"{args.seconds:g} s @ {args.rate:g} Hz, torch (est.)": f"{(n_long - 1) / sps_torch:.1f} s",
            f"{args.seconds:g} s @ {args.rate:g} Hz, fast": f"{(n_long - 1) / sps_fast:.2f} s",
        }
        rows.append(row)
        print(f"  done: {row}", flush=True)
    table = rep.table(rows)
    rep.write()
    return table


if __name__ == "__main__":
    main()
