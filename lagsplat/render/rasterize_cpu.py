"""The compiled CPU backend of the rasteriser (numba tile kernels, :mod:`lagsplat.render.cpu_kernels`) with its autograd function.

Follows the rule of :mod:`lagsplat.render.rule` exactly; the switch is :func:`lagsplat.render.rasterize.rasterize`.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor
from torch.profiler import record_function

from lagsplat.render.rule import EPS2D, pixel_bounds, prepare_gaussians

__all__ = ["rasterize_cpu", "rasterize_cpu_jvp", "run_parallel", "numba_available"]


def _cpu_render(means, conic, opac, colors, r2, bounds, background, height, width) -> Tensor:
    """Inference path of :func:`rasterize_cpu`: the same image, no autograd record."""
    k = _prepare_kernel(means, conic, opac, colors, r2, bounds, background, height, width)
    return torch.from_numpy(_cpu_forward(k, colors.shape[0], colors.shape[2], height, width))


def _cpu_forward(k: dict, B: int, C: int, height: int, width: int) -> np.ndarray:
    """Run ``forward_kernel`` on the binned inputs ``k`` of :func:`_prepare_kernel`; float32 ``[B,C,H,W]``."""
    from lagsplat.render import cpu_kernels as ck

    out = np.empty((B, C, height, width), np.float32)
    x0, x1, y0, y1 = k["bounds"]
    run_parallel(ck.forward_kernel, k["pairs"], k["key_start"], *k["arrays"], x0, x1, y0, y1, height, width, k["ntx"], k["n_tiles"], out)
    return out


def _prepare_kernel(means, conic, opac, colors, r2, bounds, background, height, width) -> dict:
    """Bin the (tile, primitive) pairs and lay the inputs out as the compiled kernels take them.

    Returns ``pairs``, ``key_start``, ``ntx``, ``n_tiles``, ``bounds`` (x0, x1,
    y0, y1 as int64 NumPy arrays) and ``arrays`` = (means, conic, opacity, r2,
    colours, background), float32 NumPy, primitives flattened to ``B K``.
    """
    from lagsplat.render import cpu_kernels as ck

    B, K, C = colors.shape
    tile = ck.TILE
    ntx, nty = math.ceil(width / tile), math.ceil(height / tile)
    n_tiles = ntx * nty
    x0, x1, y0, y1, valid = (v.reshape(-1).numpy() for v in bounds)
    pairs, key_start = ck.bin_pairs(x0, x1, y0, y1, valid, K, n_tiles, ntx, tile)
    arr = lambda t: np.ascontiguousarray(t.detach().reshape(B * K, -1).numpy(), dtype=np.float32)  # noqa: E731
    m, cn, col = arr(means), arr(conic), arr(colors)
    op, rr = arr(opac).reshape(-1), arr(r2).reshape(-1)
    bg = np.zeros(C, np.float32) if background is None else background.detach().cpu().numpy().astype(np.float32)
    return {
        "pairs": pairs, "key_start": key_start, "ntx": ntx, "n_tiles": n_tiles,
        "bounds": (x0, x1, y0, y1), "arrays": (m, cn, op, rr, col, bg),
    }


class _CpuRasterize(torch.autograd.Function):
    """Autograd wrapper of the compiled kernels in :mod:`lagsplat.render.cpu_kernels`.

    The forward pass stores only its image; the backward pass replays the
    compositing (``backward_kernel``) and sums the per-pair gradients per
    primitive (``sum_pairs``).
    """

    @staticmethod
    def forward(ctx, means, conic, opac, colors, r2, bounds, background, height, width):
        B, K, C = colors.shape
        with record_function("rasterize.cpu.forward"):
            k = _prepare_kernel(means, conic, opac, colors, r2, bounds, background, height, width)
            out = _cpu_forward(k, B, C, height, width)
        img = torch.from_numpy(out)
        ctx.kernel_inputs = k
        ctx.save_for_backward(img)  # an in-place edit of the output then fails loudly in backward
        ctx.dims = (B, K, C, height, width)
        return img

    @staticmethod
    def backward(ctx, grad_out):
        from lagsplat.render import cpu_kernels as ck

        with record_function("rasterize.cpu.backward"):
            k, out = ctx.kernel_inputs, ctx.saved_tensors[0].numpy()
            B, K, C, height, width = ctx.dims
            pairs = k["pairs"]
            m, cn, op, rr, col, _ = k["arrays"]
            _, _, y0, y1 = k["bounds"]
            g_pair = np.empty((len(pairs), 6 + C), np.float32)
            go = np.ascontiguousarray(grad_out.detach().numpy(), dtype=np.float32)
            run_parallel(
                ck.backward_kernel, pairs, k["key_start"], m, cn, op, rr, col, y0, y1,
                height, width, k["ntx"], k["n_tiles"], out, go, g_pair,
            )
            slots, prim_start = ck.group_by_primitive(pairs, B * K)
            g_np = np.empty((B * K, 6 + C), np.float32)
            run_parallel(ck.sum_pairs, g_pair, slots, prim_start, g_np)
        g = torch.from_numpy(g_np)
        return (
            g[:, 0:2].reshape(B, K, 2),
            g[:, 2:5].reshape(B, K, 3),
            g[:, 5].reshape(B, K),
            g[:, 6:].reshape(B, K, C),
            None, None, None, None, None,
        )


def rasterize_cpu(
    means: Tensor,
    covs: Tensor,
    opacities: Tensor,
    colors: Tensor,
    height: int,
    width: int,
    background: Tensor | None = None,
    eps2d: float = EPS2D,
) -> Tensor:
    """Tile rasteriser with compiled (numba) CPU kernels; same image as :func:`rasterize_dense`.

    First-order gradients flow to ``means``, ``covs``, ``opacities`` and
    ``colors`` (no double backward and no forward-mode AD: use
    :func:`rasterize_tiles` for those). CPU float32 tensors only. The
    kernels use fixed 16 x 16 pixel tiles (:data:`lagsplat.render.cpu_kernels.TILE`)
    and a polynomial exponential within about one float32 ulp of ``exp``
    (:func:`~lagsplat.render.cpu_kernels.exp_neg`). The backward pass costs
    about 1.5-2 forward passes (``benchmarks/rasterizer.py``).
    Arguments and return value as :func:`rasterize_tiles`, without ``tile``.

    Raises:
        ValueError: on CUDA tensors or inconsistent shapes.
    """
    if means.device.type != "cpu":
        raise ValueError("rasterize_cpu needs CPU tensors; use backend='torch' or 'gsplat' on a GPU")
    B, K, conic, colors, r2, sxx, syy = prepare_gaussians(means, covs, opacities, colors, eps2d)
    with torch.no_grad():
        bounds = pixel_bounds(means, r2, sxx, syy, height, width)
    needs_grad = torch.is_grad_enabled() and any(t.requires_grad for t in (means, covs, opacities, colors))
    if not needs_grad:
        return _cpu_render(means, conic, opacities, colors, r2, bounds, background, height, width)
    return _CpuRasterize.apply(
        means.float(), conic.float(), opacities.float(), colors.float(), r2, bounds, background, height, width
    )


@torch.no_grad()
def rasterize_cpu_jvp(
    means: Tensor, covs: Tensor, opacities: Tensor, colors: Tensor, d_means: Tensor, d_opacities: Tensor, height: int, width: int,
    background: Tensor | None = None, eps2d: float = EPS2D,
) -> tuple[Tensor, Tensor]:
    """The image of :func:`rasterize_cpu` and its directional derivative along tangents of the means and opacities.

    The compiled forward-mode pass of :mod:`lagsplat.render.cpu_jvp` (covariances and colours held fixed).

    Args:
        means, covs, opacities, colors, height, width, background, eps2d: as :func:`rasterize_cpu`.
        d_means: ``[B,K,2]`` tangent of the means, px.
        d_opacities: ``[B,K]`` tangent of the opacities.

    Returns:
        ``(image [B,C,H,W], tangent [B,C,H,W])``, float32.

    Raises:
        ValueError: as :func:`rasterize_cpu`, or tangents of another shape.
    """
    from lagsplat.render.cpu_jvp import jvp_kernel

    if means.device.type != "cpu":
        raise ValueError("rasterize_cpu_jvp needs CPU tensors")
    if d_means.shape != means.shape or d_opacities.shape != opacities.shape:
        raise ValueError(f"tangents {tuple(d_means.shape)}, {tuple(d_opacities.shape)} must match means {tuple(means.shape)} and opacities {tuple(opacities.shape)}")
    B, K, conic, colors, r2, sxx, syy = prepare_gaussians(means, covs, opacities, colors, eps2d)
    bounds = pixel_bounds(means, r2, sxx, syy, height, width)
    k = _prepare_kernel(means, conic, opacities, colors, r2, bounds, background, height, width)
    C = colors.shape[2]
    out, out_t = np.empty((B, C, height, width), np.float32), np.empty((B, C, height, width), np.float32)
    dm = np.ascontiguousarray(d_means.detach().reshape(B * K, 2).numpy(), dtype=np.float32)
    do = np.ascontiguousarray(d_opacities.detach().reshape(B * K).numpy(), dtype=np.float32)
    x0, x1, y0, y1 = k["bounds"]
    m, cn, op, rr, col, bg = k["arrays"]
    run_parallel(jvp_kernel, k["pairs"], k["key_start"], m, cn, op, rr, col, bg, dm, do, x0, x1, y0, y1, height, width, k["ntx"], k["n_tiles"], out, out_t)
    return torch.from_numpy(out), torch.from_numpy(out_t)


def run_parallel(kernel, *args) -> None:
    """Run a parallel numba kernel, keeping torch's thread count.

    Numba's OpenMP threading layer sets the process-wide OpenMP thread count
    to ``NUMBA_NUM_THREADS`` (the machine's cores by default) at its first
    parallel launch, which torch then reads back: without the restore, a
    ``threads=`` setting is lost after the first rasterisation and results
    depend on the core count (torch's reductions are ordered by thread).
    """
    n = torch.get_num_threads()
    kernel(*args)
    if torch.get_num_threads() != n:
        torch.set_num_threads(n)


def numba_available() -> bool:
    """Whether numba is importable (the compiled CPU backend can run)."""
    try:
        import numba  # noqa: F401
    except Exception:
        return False
    return True
