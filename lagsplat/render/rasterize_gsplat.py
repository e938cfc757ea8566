"""The gsplat backend of the rasteriser: gsplat's CUDA kernels behind this project's rasteriser interface.

The switch is :func:`lagsplat.render.rasterize.rasterize`; the differences from the rule are in :func:`rasterize_gsplat`.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from lagsplat.render.rule import ALPHA_MAX, EPS2D, prepare_gaussians

__all__ = ["rasterize_gsplat", "gsplat_available"]


def gsplat_available() -> bool:
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
    B, K, conic, colors, r2, sxx, syy = prepare_gaussians(means, covs, opacities, colors, eps2d)
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
