"""Throughput of the rasteriser backends (frames per second).

Backends: ``cpu`` (numba tile kernels, :func:`lagsplat.render.rasterize_cpu.rasterize_cpu`),
``torch`` (pure-torch tile culling, :func:`~lagsplat.render.rasterize.rasterize_tiles`),
``dense`` (the ``O(B K H W)`` reference, skipped where it would need more than
``--dense-limit-gb`` of memory) and, with ``--device cuda``, ``gsplat`` (gsplat's
CUDA kernels, :func:`~lagsplat.render.rasterize_gsplat.rasterize_gsplat`). The table
also gives each backend's largest pixel difference from ``torch`` (the exact
rule) on the same scene.

Scenes are decoder-like: ``K`` Gaussians spread uniformly over the image (means
per frame, ``[B,K,2]``), shared covariances ``[K,2,2]`` with a standard deviation
of 1.5/64 of the image width (1.5 px at 64^2, 3 px at 128^2), random anisotropy
(axis ratio up to 2 either way) and orientation, opacities uniform in
[0.2, 0.9], random colours, black background.

Usage::

    python benchmarks/rasterizer.py [--repeats N] [--batch B] [--threads T]
    python benchmarks/rasterizer.py --device cuda --backends torch gsplat --batch 64

Writes what it prints to ``results/benchmarks/rasterizer.md`` (``--report PATH``, ``--no-report``).

Each configuration gets one warm-up call (this also triggers numba's
compilation, or loads its cache) and then ``--repeats`` timed calls; the table
reports ``batch / median time``. "fwd+bwd" times the forward pass and the
backward pass of ``sum(image * upstream)`` to all four inputs together;
"fwd+bwd / fwd" is the ratio of the two frame rates in the same run (1/3 would
mean a backward pass that costs two forward passes).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout without installing
import lagsplat  # noqa: E402,F401  (sets GOMP_SPINCOUNT before torch starts its threads)
import torch  # noqa: E402

import pandas as pd


from lagsplat.render.rasterize import rasterize_dense, rasterize_tiles
from lagsplat.render.rasterize_cpu import rasterize_cpu
from lagsplat.render.rasterize_gsplat import rasterize_gsplat
from _common import Report, add_report_options, env_header, time_call  # this script's folder

BACKENDS = {"cpu": rasterize_cpu, "torch": rasterize_tiles, "dense": rasterize_dense, "gsplat": rasterize_gsplat}


def make_scene(batch: int, k: int, size: int, seed: int = 0):
    """Decoder-like scene of ``k`` Gaussians on a ``size x size`` image."""
    g = torch.Generator().manual_seed(seed)
    means = torch.rand(batch, k, 2, generator=g) * size
    std = 1.5 / 64.0 * size
    ratio = torch.exp(torch.empty(k).uniform_(-math.log(2.0), math.log(2.0), generator=g))
    sx, sy = std * ratio.sqrt(), std / ratio.sqrt()
    th = torch.rand(k, generator=g) * math.pi
    c, s = torch.cos(th), torch.sin(th)
    rot = torch.stack([torch.stack([c, -s], -1), torch.stack([s, c], -1)], -2)
    covs = rot @ torch.diag_embed(torch.stack([sx**2, sy**2], -1)) @ rot.transpose(-1, -2)
    opac = 0.2 + 0.7 * torch.rand(batch, k, generator=g)
    colors = torch.rand(k, 3, generator=g)
    return means, covs, opac, colors


def dense_bytes(batch: int, k: int, size: int) -> float:
    """Rough peak memory of the dense reference: ~6 float32 tensors of B K H W."""
    return batch * k * size * size * 4.0 * 6.0


def bench_one(backend: str, batch: int, k: int, size: int, repeats: int, device: str = "cpu") -> tuple[float, float, float]:
    """Frames/s forward, frames/s forward+backward, and max |image - torch backend's image|."""
    raster = BACKENDS[backend]
    scene = make_scene(batch, k, size)
    means, covs, opac, colors = (t.to(device) for t in scene)
    upstream = torch.randn(batch, 3, size, size, generator=torch.Generator().manual_seed(1)).to(device)
    sync = torch.cuda.synchronize if device == "cuda" else (lambda: None)

    def forward():
        with torch.no_grad():
            raster(means, covs, opac, colors, size, size)
        sync()

    leaves = [t.clone().requires_grad_(True) for t in (means, covs, opac, colors)]

    def forward_backward():
        for t in leaves:
            t.grad = None
        img = raster(*leaves, size, size)
        (img * upstream).sum().backward()
        sync()

    t_fwd = time_call(forward, repeats)
    t_fb = time_call(forward_backward, repeats)
    diff = 0.0  # the torch backend is the reference itself
    if raster is not rasterize_tiles:
        with torch.no_grad():
            diff = float((raster(means, covs, opac, colors, size, size) - rasterize_tiles(means, covs, opac, colors, size, size)).abs().max())
    return batch / t_fwd, batch / t_fb, diff


def main(argv: list[str] | None = None) -> pd.DataFrame:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=5, help="timed calls per configuration (median reported)")
    ap.add_argument("--batch", type=int, default=16, help="frames per call")
    ap.add_argument("--threads", type=int, default=None, help="torch and numba threads (default: library defaults)")
    ap.add_argument("--sizes", type=int, nargs="+", default=[64, 128], help="image edge lengths in pixels")
    ap.add_argument("--gaussians", type=int, nargs="+", default=[1000, 4000], help="numbers of Gaussians")
    ap.add_argument("--backends", nargs="+", default=["cpu", "torch", "dense"], choices=list(BACKENDS))
    ap.add_argument("--device", default="cpu", choices=["cpu", "cuda"], help="where the scenes live (gsplat needs cuda, cpu needs cpu)")
    ap.add_argument("--dense-limit-gb", type=float, default=4.0, help="skip dense above this estimated memory")
    add_report_options(ap, "rasterizer")
    args = ap.parse_args(argv)

    if args.threads is not None:
        torch.set_num_threads(args.threads)
    numba_threads = "n/a"
    try:
        import numba

        if args.threads is not None:
            numba.set_num_threads(args.threads)
        numba_threads = str(numba.get_num_threads())
    except ImportError:
        pass
    rep = Report("Rasteriser throughput (frames/s)", args.report, __file__, argv)
    print(env_header(f"numba threads: {numba_threads}"))
    if args.device == "cuda":
        print(f"device: {torch.cuda.get_device_name()}")
    rep.text(f"device {args.device}, batch {args.batch}, median of {args.repeats} timed calls after one warm-up; numbers are frames/s")

    rows = []
    for size in args.sizes:
        for k in args.gaussians:
            for backend in args.backends:
                row = {"image": f"{size}x{size}", "gaussians": k, "backend": backend}
                if backend == "dense" and dense_bytes(args.batch, k, size) > args.dense_limit_gb * 2**30:
                    row["forward fps"] = row["fwd+bwd fps"] = "skipped (memory)"
                else:
                    fwd, fb, diff = bench_one(backend, args.batch, k, size, args.repeats, args.device)
                    row["forward fps"], row["fwd+bwd fps"] = f"{fwd:.1f}", f"{fb:.1f}"
                    row["fwd+bwd / fwd"] = f"{fb / fwd:.2f}"
                    row["max |diff| vs torch"] = f"{diff:.1e}"
                rows.append(row)
                print(f"  done: {row}", flush=True)
    table = rep.table(rows)
    rep.write()
    return table


if __name__ == "__main__":
    main()
