"""Differentiable 2D Gaussian rasterisation on the CPU (and the backend switch).

Compositing rule (fixed; every backend must render the same image)
-------------------------------------------------------------------
Pixel ``(i, j)`` (row ``i``, column ``j``) has its centre at ``p = (j + 0.5, i + 0.5)``
in pixel units, x to the right, y down. Each Gaussian ``k`` has a centre
``mu_k`` (pixels), a covariance ``Sigma_k`` (pixels^2), an opacity ``o_k`` and a
colour ``c_k``. With the anti-aliasing dilation ``Sigma'_k = Sigma_k + eps2d I``
and ``d2_kp = (p - mu_k)^T Sigma'_k^-1 (p - mu_k)``:

    a_kp = min(alpha_max, o_k exp(-d2_kp / 2))   if d2_kp <= 9 and a_kp >= 1/255
    a_kp = 0                                     otherwise

    C(p) = sum_k c_k a_kp prod_{j<k} (1 - a_jp)  +  bg prod_k (1 - a_kp)

i.e. front-to-back "over" compositing in ascending primitive index: all
primitives of the 2D decoder share one depth, so index order is the explicit,
deterministic tie-break (the reference gsplat path relies on its sort being
stable, which gives the same order; see notes, §4.3). The constants
(``eps2d = 0.3`` px^2, 3-sigma support, 1/255 cut, ``alpha_max = 0.99``) are
those of the classic 3DGS rasteriser. The CPU and torch backends follow the
rule exactly; :func:`rasterize_gsplat` runs gsplat's own CUDA kernels, which
differ in three small, documented ways (its docstring; about 55 dB PSNR on
trained decoders).

Culling
-------
A Gaussian only touches pixels where ``a_kp >= 1/255``, i.e. where
``d2 <= r2 = min(9, 2 ln(255 o_k))``. The axis-aligned extent of that ellipse is
``r sqrt(Sigma'_xx)`` by ``r sqrt(Sigma'_yy)``; :func:`rasterize_tiles` lists the
``tile x tile`` pixel tiles each extent overlaps, sorts the (tile, primitive)
pairs by tile (stable, so index order survives) and composites every pair on its
tile's pixels. Transmittance is an exclusive segmented cumulative sum of
``log(1 - a)`` (accumulated in float64). Cost is proportional to the number of
(tile, primitive) pairs, not to ``K H W``. :func:`rasterize_dense` evaluates the
same rule on all ``K x H x W`` pairs; it is the test reference.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
import torch
from torch import Tensor
from torch.profiler import record_function

__all__ = [
    "rasterize",
    "rasterize_tiles",
    "rasterize_dense",
    "rasterize_cpu",
    "rasterize_gsplat",
    "Backend",
    "ALPHA_MIN",
    "ALPHA_MAX",
    "EPS2D",
    "SUPPORT_SIGMA",
]

Backend = Literal["auto", "cpu", "torch", "dense", "gsplat"]

ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
EPS2D = 0.3
SUPPORT_SIGMA = 3.0


def _prepare(means: Tensor, covs: Tensor, opacities: Tensor, colors: Tensor, eps2d: float):
    """Broadcast inputs; return conic (inverse covariance) entries and support radius^2."""
    if means.dim() != 3 or means.shape[-1] != 2:
        raise ValueError(f"means must be [B,K,2], got {tuple(means.shape)}")
    B, K, _ = means.shape
    if opacities.shape != (B, K):
        raise ValueError(f"opacities must be [B,K]=[{B},{K}], got {tuple(opacities.shape)}")
    if covs.dim() == 3 and covs.shape == (K, 2, 2):
        covs = covs.unsqueeze(0).expand(B, K, 2, 2)
    if covs.shape != (B, K, 2, 2):
        raise ValueError(f"covs must be [K,2,2] or [B,K,2,2], got {tuple(covs.shape)}")
    if colors.dim() == 2 and colors.shape[0] == K:
        colors = colors.unsqueeze(0).expand(B, K, colors.shape[-1])
    if colors.dim() != 3 or colors.shape[:2] != (B, K):
        raise ValueError(f"colors must be [K,C] or [B,K,C], got {tuple(colors.shape)}")
    sxx = covs[..., 0, 0] + eps2d
    syy = covs[..., 1, 1] + eps2d
    sxy = 0.5 * (covs[..., 0, 1] + covs[..., 1, 0])
    det = (sxx * syy - sxy * sxy).clamp_min(1e-12)
    conic = torch.stack([syy / det, -sxy / det, sxx / det], dim=-1)  # [B,K,3]: (a, b, c)
    with torch.no_grad():
        o = opacities.clamp(0.0, 1.0)
        r2 = torch.where(
            o > ALPHA_MIN,
            torch.clamp(2.0 * torch.log(255.0 * o.clamp_min(1e-30)), max=SUPPORT_SIGMA**2),
            torch.full_like(o, -1.0),
        )
    return B, K, conic, colors, r2, sxx.detach(), syy.detach()


def _pixel_bounds(means: Tensor, r2: Tensor, sxx: Tensor, syy: Tensor, height: int, width: int):
    """Inclusive pixel bounds (int64 ``[B,K]`` each) of each support ellipse, and a validity mask.

    Pixel ``j`` is touched iff ``|j + 0.5 - mu_x| <= r sqrt(Sigma'_xx)`` (same in y).
    """
    mx, my = means[..., 0].detach(), means[..., 1].detach()
    valid = r2 > 0
    r2c = r2.clamp_min(0.0)
    ex, ey = torch.sqrt(r2c * sxx), torch.sqrt(r2c * syy)
    x0 = torch.ceil(mx - ex - 0.5).clamp(min=0)
    x1 = torch.floor(mx + ex - 0.5).clamp(max=width - 1)
    y0 = torch.ceil(my - ey - 0.5).clamp(min=0)
    y1 = torch.floor(my + ey - 0.5).clamp(max=height - 1)
    valid = valid & (x0 <= x1) & (y0 <= y1) & torch.isfinite(mx) & torch.isfinite(my)
    fix = lambda v: torch.nan_to_num(v, nan=0.0, posinf=0.0, neginf=0.0).long()  # noqa: E731
    return fix(x0), fix(x1), fix(y0), fix(y1), valid


def _alpha(d2: Tensor, opac: Tensor, r2: Tensor) -> Tensor:
    a = torch.clamp(opac * torch.exp(-0.5 * d2), max=ALPHA_MAX)
    keep = (d2 <= r2) & (a >= ALPHA_MIN)
    return torch.where(keep, a, torch.zeros_like(a))


def rasterize_dense(
    means: Tensor,
    covs: Tensor,
    opacities: Tensor,
    colors: Tensor,
    height: int,
    width: int,
    background: Tensor | None = None,
    eps2d: float = EPS2D,
) -> Tensor:
    """Reference rasteriser: the compositing rule on every (primitive, pixel) pair.

    Memory and time are ``O(B K H W)``; use it for tests and small images only.

    Args:
        means: ``[B,K,2]`` centres in pixels (x right, y down; pixel centres at ``+0.5``).
        covs: ``[K,2,2]`` or ``[B,K,2,2]`` covariances in pixels^2.
        opacities: ``[B,K]`` opacities in [0, 1].
        colors: ``[K,C]`` or ``[B,K,C]`` colours.
        height, width: output size in pixels.
        background: ``[C]`` colour behind everything (default black).
        eps2d: dilation added to each covariance, pixels^2.

    Returns:
        ``[B,C,H,W]`` image.

    Raises:
        ValueError: on inconsistent shapes.
    """
    B, K, conic, colors, r2, _, _ = _prepare(means, covs, opacities, colors, eps2d)
    dev, dt = means.device, means.dtype
    ys = torch.arange(height, device=dev, dtype=dt) + 0.5
    xs = torch.arange(width, device=dev, dtype=dt) + 0.5
    dx = xs.view(1, 1, 1, width) - means[..., 0].view(B, K, 1, 1)
    dy = ys.view(1, 1, height, 1) - means[..., 1].view(B, K, 1, 1)
    a, b, c = (conic[..., i].view(B, K, 1, 1) for i in range(3))
    d2 = a * dx * dx + 2.0 * b * dx * dy + c * dy * dy
    alpha = _alpha(d2, opacities.view(B, K, 1, 1), r2.view(B, K, 1, 1))  # [B,K,H,W]
    log1m = torch.log1p(-alpha).double()
    cs = torch.cumsum(log1m, dim=1)
    trans = torch.exp(cs - log1m).to(dt)  # exclusive product over j < k
    w = trans * alpha
    img = torch.einsum("bkhw,bkc->bchw", w, colors)
    if background is not None:
        t_final = torch.exp(cs[:, -1]).to(dt)  # [B,H,W]
        img = img + t_final.unsqueeze(1) * background.view(1, -1, 1, 1).to(dt)
    return img


def rasterize_tiles(
    means: Tensor,
    covs: Tensor,
    opacities: Tensor,
    colors: Tensor,
    height: int,
    width: int,
    background: Tensor | None = None,
    eps2d: float = EPS2D,
    tile: int = 8,
) -> Tensor:
    """Tile-culled rasteriser; same image as :func:`rasterize_dense`, differentiable.

    Gradients flow to ``means``, ``covs``, ``opacities`` and ``colors``.
    Arguments and return value as :func:`rasterize_dense`, plus ``tile``, the
    edge of the square pixel tiles used for culling.
    """
    B, K, conic, colors, r2, sxx, syy = _prepare(means, covs, opacities, colors, eps2d)
    dev, dt = means.device, means.dtype
    C = colors.shape[-1]
    ntx, nty = math.ceil(width / tile), math.ceil(height / tile)
    n_tiles = ntx * nty

    with torch.no_grad():
        x0, x1, y0, y1, valid = _pixel_bounds(means, r2, sxx, syy, height, width)
        tx0 = torch.div(x0, tile, rounding_mode="floor")
        tx1 = torch.div(x1, tile, rounding_mode="floor")
        ty0 = torch.div(y0, tile, rounding_mode="floor")
        ty1 = torch.div(y1, tile, rounding_mode="floor")
        nwx = (tx1 - tx0 + 1).clamp_min(0)
        counts = torch.where(valid, nwx * (ty1 - ty0 + 1).clamp_min(0), torch.zeros_like(nwx)).reshape(-1)
        n_pairs = int(counts.sum())
        flat = torch.repeat_interleave(torch.arange(B * K, device=dev), counts)  # (b,k) per pair
        offsets = torch.cumsum(counts, 0) - counts
        local = torch.arange(n_pairs, device=dev) - offsets[flat]
        w_flat = nwx.reshape(-1)[flat]
        tx = tx0.reshape(-1)[flat] + local % w_flat
        ty = ty0.reshape(-1)[flat] + torch.div(local, w_flat, rounding_mode="floor")
        bidx = torch.div(flat, K, rounding_mode="floor")
        key = bidx * n_tiles + ty * ntx + tx
        key, order = torch.sort(key, stable=True)
        flat, tx, ty = flat[order], tx[order], ty[order]
        seg_keys, seg_counts = torch.unique_consecutive(key, return_counts=True)
        seg_start = torch.cumsum(seg_counts, 0) - seg_counts
        pair_start = torch.repeat_interleave(seg_start, seg_counts)
        lin = torch.arange(tile, device=dev, dtype=dt) + 0.5
        px = (tx * tile).to(dt).unsqueeze(1) + lin.unsqueeze(0)  # [P, t]
        py = (ty * tile).to(dt).unsqueeze(1) + lin.unsqueeze(0)

    mu = means.reshape(B * K, 2)[flat]  # [P,2]
    cn = conic.reshape(B * K, 3)[flat]  # [P,3]
    op = opacities.reshape(B * K)[flat]
    dx = (px - mu[:, :1]).unsqueeze(1)  # [P,1,t]  (columns)
    dy = (py - mu[:, 1:]).unsqueeze(2)  # [P,t,1]  (rows)
    d2 = cn[:, 0, None, None] * dx * dx + 2.0 * cn[:, 1, None, None] * dx * dy + cn[:, 2, None, None] * dy * dy
    alpha = _alpha(d2, op[:, None, None], r2.reshape(-1)[flat][:, None, None]).reshape(n_pairs, tile * tile)
    log1m = torch.log1p(-alpha)
    cs = torch.cumsum(log1m.double(), dim=0)
    excl = cs - log1m.double()
    trans = torch.exp(excl - excl[pair_start]).to(dt)
    wgt = trans * alpha  # [P, t*t]
    col = colors.reshape(B * K, C)[flat]  # [P,C]
    out = torch.zeros(B * n_tiles, tile * tile, C, device=dev, dtype=dt)
    out = out.index_add(0, key, wgt.unsqueeze(-1) * col.unsqueeze(1))
    if background is not None:
        logt = torch.zeros(B * n_tiles, tile * tile, device=dev, dtype=dt).index_add(0, key, log1m)
        out = out + torch.exp(logt).unsqueeze(-1) * background.to(dt).view(1, 1, C)
    img = out.view(B, nty, ntx, tile, tile, C).permute(0, 5, 1, 3, 2, 4).reshape(B, C, nty * tile, ntx * tile)
    return img[:, :, :height, :width]


def _cpu_render(means, conic, opac, colors, r2, bounds, background, height, width) -> Tensor:
    """Inference path of :func:`rasterize_cpu`: the same image, no autograd record."""
    k = _prepare_kernel(means, conic, opac, colors, r2, bounds, background, height, width)
    return torch.from_numpy(_cpu_forward(k, colors.shape[0], colors.shape[2], height, width))


def _cpu_forward(k: dict, B: int, C: int, height: int, width: int) -> np.ndarray:
    """Run ``forward_kernel`` on the binned inputs ``k`` of :func:`_prepare_kernel`; float32 ``[B,C,H,W]``."""
    from lagsplat.render import cpu_kernels as ck

    out = np.empty((B, C, height, width), np.float32)
    x0, x1, y0, y1 = k["bounds"]
    _parallel(ck.forward_kernel, k["pairs"], k["key_start"], *k["arrays"], x0, x1, y0, y1, height, width, k["ntx"], k["n_tiles"], out)
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
            _parallel(
                ck.backward_kernel, pairs, k["key_start"], m, cn, op, rr, col, y0, y1,
                height, width, k["ntx"], k["n_tiles"], out, go, g_pair,
            )
            slots, prim_start = ck.group_by_primitive(pairs, B * K)
            g_np = np.empty((B * K, 6 + C), np.float32)
            _parallel(ck.sum_pairs, g_pair, slots, prim_start, g_np)
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
    B, K, conic, colors, r2, sxx, syy = _prepare(means, covs, opacities, colors, eps2d)
    with torch.no_grad():
        bounds = _pixel_bounds(means, r2, sxx, syy, height, width)
    needs_grad = torch.is_grad_enabled() and any(t.requires_grad for t in (means, covs, opacities, colors))
    if not needs_grad:
        return _cpu_render(means, conic, opacities, colors, r2, bounds, background, height, width)
    return _CpuRasterize.apply(
        means.float(), conic.float(), opacities.float(), colors.float(), r2, bounds, background, height, width
    )


def _parallel(kernel, *args) -> None:
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


def _numba_available() -> bool:
    try:
        import numba  # noqa: F401
    except Exception:
        return False
    return True


def _gsplat_available() -> bool:
    """Whether the gsplat backend can run here: gsplat importable and a CUDA device present."""
    try:
        import gsplat  # noqa: F401
    except Exception:
        return False
    return torch.cuda.is_available()


def rasterize_gsplat(
    means: Tensor,
    covs: Tensor,
    opacities: Tensor,
    colors: Tensor,
    height: int,
    width: int,
    background: Tensor | None = None,
    eps2d: float = EPS2D,
    tile: int = 16,
) -> Tensor:
    """Rasterise with gsplat's CUDA tile kernels (``isect_tiles`` + ``rasterize_to_pixels``).

    The primitives are already 2D, so gsplat's projection is skipped: this
    module computes the dilated conics and the per-axis support radii, gives
    every primitive depth 0 and lets gsplat bin (stable radix sort, so
    ascending primitive index is kept within a tile, as the rule asks) and
    composite. Opacities are capped at :data:`ALPHA_MAX` before the call.
    What gsplat does differently from the rule of this module, all measured
    by ``tests/test_render.py::test_gsplat_*`` on a CUDA machine:

    * no per-pixel 3-sigma cut: where ``o > 0.35`` the Gaussian's tail beyond
      ``d2 = 9`` (alpha between 1/255 and ``0.011 o``) is drawn on the tiles
      its support touches;
    * its own cap is 0.999, so for ``o`` in (0.99, 1] the centre is drawn at
      ``0.99 exp(-d2/2)`` instead of ``min(0.99, o exp(-d2/2))``;
    * a pixel stops compositing once its transmittance would fall below 1e-4.

    On scenes with every opacity below 0.35 it renders the same image as
    :func:`rasterize_dense` to 1e-4 (the transmittance stop). First-order gradients flow to
    ``means``, ``covs``, ``opacities`` and ``colors`` (no forward-mode AD:
    :func:`lagsplat.chart.visibility_metric` uses :func:`rasterize_tiles`).

    Args:
        means, covs, opacities, colors, height, width, background, eps2d: as
            :func:`rasterize_dense`; CUDA float32 tensors.
        tile: gsplat's tile edge in pixels (16, its usual value).

    Returns:
        ``[B,C,H,W]`` image on the input's device.

    Raises:
        RuntimeError: if gsplat is not installed or the tensors are not on a CUDA device.
        ValueError: on inconsistent shapes.
    """
    if means.device.type != "cuda":
        raise RuntimeError(f"the gsplat backend needs CUDA tensors, got device {means.device}; use backend='cpu' or 'torch'")
    try:
        from gsplat.cuda._wrapper import isect_offset_encode, isect_tiles, rasterize_to_pixels
    except ImportError as exc:
        raise RuntimeError(f"the gsplat backend needs the gsplat package (pip install gsplat): {exc}") from exc
    B, K, conic, colors, r2, sxx, syy = _prepare(means, covs, opacities, colors, eps2d)
    C = colors.shape[-1]
    ntx, nty = math.ceil(width / tile), math.ceil(height / tile)
    with torch.no_grad():
        r = torch.sqrt(r2.clamp_min(0.0))
        radii = torch.stack([torch.ceil(r * torch.sqrt(sxx)), torch.ceil(r * torch.sqrt(syy))], -1)
        ok = (r2 > 0) & torch.isfinite(means).all(-1)
        radii = torch.where(ok.unsqueeze(-1), radii, torch.zeros_like(radii)).int()
        depths = torch.zeros(B, K, device=means.device, dtype=torch.float32)
        _, isect_ids, flatten_ids = isect_tiles(means.detach().float(), radii, depths, tile, ntx, nty)
        offsets = isect_offset_encode(isect_ids, B, ntx, nty)
    bg = None if background is None else background.float().view(1, C).expand(B, C)
    img, _ = rasterize_to_pixels(
        means.float(), conic.float(), colors.float(), opacities.float().clamp(max=ALPHA_MAX),
        width, height, tile, offsets, flatten_ids, backgrounds=bg,
    )
    return img.permute(0, 3, 1, 2)


def rasterize(
    means: Tensor,
    covs: Tensor,
    opacities: Tensor,
    colors: Tensor,
    height: int,
    width: int,
    background: Tensor | None = None,
    backend: Backend = "auto",
    eps2d: float = EPS2D,
    tile: int = 8,
) -> Tensor:
    """Render 2D Gaussians with the compositing rule of this module.

    Args:
        means: ``[B,K,2]`` centres in pixels.
        covs: ``[K,2,2]`` or ``[B,K,2,2]`` covariances in pixels^2.
        opacities: ``[B,K]`` in [0, 1].
        colors: ``[K,C]`` or ``[B,K,C]``.
        height, width: output size in pixels.
        background: ``[C]`` colour (default black).
        backend: ``"cpu"`` (compiled tile kernels, the default on CPU),
            ``"torch"`` (tile-culled in pure torch, any device, supports
            double backward and forward-mode AD), ``"dense"`` (reference),
            ``"gsplat"`` (gsplat's CUDA kernels, :func:`rasterize_gsplat`) or
            ``"auto"`` (``"cpu"`` for CPU tensors when numba is importable,
            ``"gsplat"`` for CUDA tensors when gsplat is installed, else ``"torch"``).
        eps2d: covariance dilation in pixels^2.
        tile: culling tile edge in pixels (torch backend; the compiled CPU
            kernels use 16 x 16 tiles, gsplat its own).

    Returns:
        ``[B,C,H,W]`` image.

    Raises:
        ValueError: on inconsistent shapes or an unknown backend.
        RuntimeError: if ``"gsplat"`` is asked for without gsplat or CUDA tensors.
    """
    if backend == "auto":
        if means.device.type == "cpu":
            backend = "cpu" if _numba_available() else "torch"
        else:
            backend = "gsplat" if means.device.type == "cuda" and _gsplat_available() else "torch"
    if backend == "cpu":
        return rasterize_cpu(means, covs, opacities, colors, height, width, background, eps2d)
    if backend == "torch":
        return rasterize_tiles(means, covs, opacities, colors, height, width, background, eps2d, tile)
    if backend == "dense":
        return rasterize_dense(means, covs, opacities, colors, height, width, background, eps2d)
    if backend == "gsplat":
        return rasterize_gsplat(means, covs, opacities, colors, height, width, background, eps2d)
    raise ValueError(f"unknown rasterizer backend {backend!r}; expected auto, torch, dense or gsplat")
