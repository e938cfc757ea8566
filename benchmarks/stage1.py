"""Stage-1 training speed: seconds per step, where a step spends them, and a side-by-side comparison.

Three operating points: a synthetic pendulum clip rendered at the setting's size
(:func:`lagsplat.synth.pendulum.make_pendulum_clip`, 20 s at 30 fps), and a user's clip
(a realistic-suite render, ``lagsplat.synth.realistic``, rendered first if it is not cached):

========== ========= ====== ========= ===== ===============================
setting    image     batch  Gaussians d     Stage-1 settings
========== ========= ====== ========= ===== ===============================
toy        64 x 64   16     1024      1     ``system=toy`` (the main job)
softrobot  32 x 32   64     2048      4     ``system=krauss_2seg``, batch 64
realistic  48 x 64   16     1024      1     ``system=realistic``: the suite's 128 x 128
                                              pendulum, cropped and resized by the
                                              automatic preparation as ingest does
========== ========= ====== ========= ===== ===============================

For each it prints

* s/step and frames/s of :func:`lagsplat.train.stage1.train_stage1`, as the
  slope between a run of ``--steps / 3`` and one of ``--steps`` steps (set-up
  and encoding the clip cancel out), each run in a fresh process after a
  3-step run that compiles numba's kernels into their cache. The cost of a
  step changes as the decoder trains (its primitives' sizes and opacities
  set the rasteriser's work), so too short a run
  misjudges it: the default 100 -> 300 steps is within 10 % of a whole
  1500-step toy run on this checkout;
* the shares of a step's wall time by phase over ``--profile-steps`` steps:
  the blocks of ``train_stage1`` labelled for ``torch.profiler`` (encode,
  decode = conditioning + rasteriser forward, loss, backward = autograd incl.
  the rasteriser's backward, optimizer), timed by wall clock, and the
  rasteriser's own forward and backward inside them, so "not rasteriser" is
  the rest of the step ("steps / run": the labelled blocks' share of the
  run, set-up excluded from the shares);
* the rasteriser's forward and forward+backward frame rates on a
  decoder-like scene of the setting's size (``benchmarks/rasterizer.py``) and
  their ratio.

With ``--against REF`` the s/step of the git commit ``REF`` (checked out in a
temporary worktree, its own ``lagsplat`` imported) is measured in the same
run, alternating with this checkout for ``--rounds`` rounds; the table gives
both medians and the speed-up, so a change is judged as a ratio on a noisy
machine.

Usage::

    python benchmarks/stage1.py [--settings toy softrobot] [--steps 300] [--against 2663fff] [--rounds 2]

Prints figures and writes them to ``results/benchmarks/stage1.md``
(``--report PATH``, ``--no-report``); asserts nothing.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import subprocess
import sys
import time
from pathlib import Path

_USER_ENV = dict(os.environ)  # before lagsplat sets its OpenMP defaults: each checkout sets its own
HERE = Path(__file__).resolve().parent
ROOT = Path(os.environ.get("LAGSPLAT_ROOT", HERE.parent))
sys.path.insert(0, str(ROOT))  # the checkout under test (a worktree of another commit with --against)

SETTINGS = {  # the system whose configured Stage-1 settings are used, and what is set on top
    "toy": {"system": "toy", "size": 64, "set": {}},
    "softrobot": {"system": "krauss_2seg", "size": 32, "set": {"batch": 64}},
    # a user's clip: the realistic suite's 128 x 128 pendulum, prepared automatically (crop and resolution) as ingest does
    "realistic": {"system": "realistic", "clip": "pendulum-none-s0-128", "set": {}},
}
REALISTIC_CACHE = Path(os.environ.get("LAGSPLAT_REALISTIC_CACHE", HERE.parent / "data" / "cache" / "realistic"))
PHASES = ("stage1.encode", "stage1.decode", "stage1.loss", "stage1.backward", "stage1.optimizer", "stage1.recycle")
RASTER = ("rasterize.cpu.forward", "rasterize.cpu.backward")


def _config(setting: str, steps: int):
    """The setting's Stage-1 config and ``d``.

    The config is the checkout's own ``conf/`` for the setting's system (so
    each commit runs with the settings it shipped), with ``steps`` and
    recycling off (it starts after 500 steps anyway).
    """
    from omegaconf import OmegaConf

    from lagsplat.cli import compose
    from lagsplat.train.stage1 import Stage1Config

    s = SETTINGS[setting]
    os.environ["LAGSPLAT_CONF"] = str(ROOT / "conf")
    cfg = compose([f"system={s['system']}"])
    stage1 = {**OmegaConf.to_container(cfg.stage1, resolve=True), **s["set"], "steps": steps, "recycle_warmup": 10**9}
    return Stage1Config.from_mapping(stage1), int(cfg.system.d)


def _clip(setting: str):
    """The setting's clip: the synthetic pendulum at its size, or a realistic-suite clip (rendered into
    ``data/cache/realistic`` if it is not there) ingested with the ``realistic`` system's automatic preparation."""
    s = SETTINGS[setting]
    if "clip" not in s:
        from lagsplat.synth.pendulum import make_pendulum_clip

        return make_pendulum_clip(size=(s["size"], s["size"]))
    from lagsplat.cli import compose
    from lagsplat.ingest import ingest

    path = REALISTIC_CACHE / f"{s['clip']}.mp4"
    if not path.exists():
        from lagsplat.synth.realistic import make_clip

        make_clip(s["clip"], REALISTIC_CACHE)
    os.environ["LAGSPLAT_CONF"] = str(ROOT / "conf")
    from omegaconf import OmegaConf

    cfg = compose([f"system={s['system']}", f"system.source.path={path}"])
    system = OmegaConf.to_container(cfg.system, resolve=True)
    system.update(crop="auto", resize="auto", split={"train_fraction": "auto"})  # what the ingest stage does for a recording
    return ingest(system)


def _size(setting: str) -> int:
    """The edge (px) of the square scene the rasteriser ratio is timed on: the setting's, or the prepared clip's longer side."""
    s = SETTINGS[setting]
    return s["size"] if "size" in s else max(_clip(setting).images.shape[1:3])


def worker(setting: str, steps: int, threads: int) -> dict:
    """Time one ``train_stage1`` run of ``steps`` steps in this process; JSON-able result."""
    import lagsplat  # noqa: F401  (thread settings before torch starts its pool)
    import torch

    from lagsplat.train.stage1 import train_stage1

    torch.set_num_threads(threads)
    clip, (cfg, d) = _clip(setting), _config(setting, steps)
    t0 = time.perf_counter()
    train_stage1(clip, cfg, d, seed=0, progress=False)
    return {"seconds": time.perf_counter() - t0, "steps": steps}


def _run_worker(root: Path, setting: str, steps: int, threads: int) -> float:
    """Wall time (s) of a ``steps``-step run by the checkout at ``root``, in a fresh process."""
    env = {**_USER_ENV, "LAGSPLAT_ROOT": str(root), "PYTHONPATH": str(root)}
    cmd = [sys.executable, str(HERE / "stage1.py"), "--worker", setting, "--steps", str(steps), "--threads", str(threads)]
    out = subprocess.run(cmd, env=env, check=True, capture_output=True, text=True).stdout
    return float(json.loads(out.strip().splitlines()[-1])["seconds"])


def seconds_per_step(root: Path, setting: str, steps: int, threads: int) -> float:
    """Slope of wall time against steps between runs of ``steps // 3`` and ``steps`` steps.

    A 3-step run goes first: it compiles the checkout's numba kernels into their cache, which the
    timed runs then load. Without it the short run pays the compilation and the long one does not,
    and the slope reads a step several times faster than it is (0.003 s against 0.037 s, toy).
    """
    _run_worker(root, setting, 3, threads)
    short = max(1, steps // 3)
    t_short = _run_worker(root, setting, short, threads)
    t_long = _run_worker(root, setting, steps, threads)
    return (t_long - t_short) / (steps - short)


class _PhaseClock:
    """Stands in for ``torch.profiler.record_function``: accumulates the wall time spent in each labelled block.

    CPU operations run synchronously, so a block's wall time is its cost; no
    profiler overhead is added to the many small operations of a step.
    """

    def __init__(self) -> None:
        self.totals: dict[str, float] = {}

    @contextlib.contextmanager
    def __call__(self, name: str):
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.totals[name] = self.totals.get(name, 0.0) + time.perf_counter() - t0


def phase_shares(setting: str, steps: int) -> dict[str, float]:
    """Share of the wall time of ``steps`` Stage-1 steps spent in each labelled phase (after a warm-up run)."""
    from dataclasses import replace

    from lagsplat.render import rasterize_cpu as rasterize
    from lagsplat.train import stage1

    clip, (cfg, d) = _clip(setting), _config(setting, steps)
    stage1.train_stage1(clip, replace(cfg, steps=3), d, progress=False)  # compile / warm up outside the measurement
    clock = _PhaseClock()
    saved = stage1.record_function, rasterize.record_function
    stage1.record_function = rasterize.record_function = clock
    try:
        t0 = time.perf_counter()
        stage1.train_stage1(clip, cfg, d, progress=False)
        wall = time.perf_counter() - t0
    finally:
        stage1.record_function, rasterize.record_function = saved
    totals = clock.totals
    step_total = sum(totals.get(k, 0.0) for k in PHASES)
    shares = {k.split(".", 1)[1] if k in PHASES else k.replace("rasterize.cpu.", "rasterise "): v / step_total for k, v in totals.items()}
    shares["not rasteriser"] = 1.0 - sum(totals.get(k, 0.0) for k in RASTER) / step_total
    shares["steps / run"] = step_total / wall
    return shares


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--settings", nargs="+", default=list(SETTINGS), choices=list(SETTINGS))
    ap.add_argument("--steps", type=int, default=300, help="steps of the longer timed run (the shorter has a third)")
    ap.add_argument("--profile-steps", type=int, default=60, help="steps timed by phase for the shares")
    ap.add_argument("--threads", type=int, default=2, help="torch and numba threads")
    sys.path.insert(0, str(HERE))
    from _common import Report, add_comparison_options, add_report_options, against_columns, alternating_medians, checkouts, env_header

    add_comparison_options(ap)
    add_report_options(ap, "stage1")
    args = ap.parse_args(argv)
    if args.worker:
        print(json.dumps(worker(args.worker, args.steps, args.threads)))
        return

    import lagsplat  # noqa: F401
    import torch

    from rasterizer import bench_one

    torch.set_num_threads(args.threads)
    import numba

    numba.set_num_threads(args.threads)
    rep = Report("Stage-1 training speed", args.report, __file__, argv)
    print(env_header(f"numba threads: {numba.get_num_threads()}"), f"; load average {os.getloadavg()[0]:.2f}")
    rep.text(
        f"s/step: slope between runs of {max(1, args.steps // 3)} and {args.steps} steps, each in a fresh process, median of {args.rounds} "
        f"round(s); phase shares over {args.profile_steps} steps; rasteriser ratio at the setting's batch and size (5 timed calls)"
    )
    with checkouts(args.against) as roots:
        rows = []
        for setting in args.settings:
            cfg, _ = _config(setting, 1)
            medians = alternating_medians(roots, args.rounds, lambda root: seconds_per_step(root, setting, args.steps, args.threads))
            base = medians["this checkout"]
            row = {"setting": setting, "s/step": f"{base:.4f}", "frames/s": f"{cfg.batch / base:.0f}", **against_columns(medians, "s/step")}
            fwd, fb, _ = bench_one("cpu", cfg.batch, cfg.n_gaussians, _size(setting), 5)
            row["raster fwd+bwd / fwd"] = f"{fb / fwd:.2f}"
            rows.append(row)
            print(f"  done: {row}", flush=True)
        rep.table(rows)
        shares = [{"setting": st, **{k: f"{v:.0%}" for k, v in phase_shares(st, args.profile_steps).items()}} for st in args.settings]
        rep.table(shares, title="share of a step's wall time by phase (this checkout):")
        rep.write()

if __name__ == "__main__":
    main()
