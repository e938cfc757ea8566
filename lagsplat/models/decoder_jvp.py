"""The 2-D conditioned decoder's image and its derivative along a direction of the state, in one compiled pass.

For the visibility metric (paper Eq. 6) :func:`render_jvp` gives ``J(z) v`` for a batch of states: the state
enters the render only through each primitive's conditional mean and latent gate (paper §3.2; the
conditional covariance and the colours are constant), so their tangents come from forward-mode AD on that
small map, and the image's tangent from the compiled rasteriser's forward-mode pass
(:func:`lagsplat.render.rasterize_cpu.rasterize_cpu_jvp`). The static layer and the clamp to ``[0, 1]``
follow the rule of :meth:`~lagsplat.models.decoder.ConditionedGaussians.render`.
"""

from __future__ import annotations

import torch
import torch.autograd.forward_ad as fwAD
from torch import Tensor

from lagsplat.models.decoder import ConditionedGaussians

__all__ = ["render_jvp", "supports_render_jvp"]


def supports_render_jvp(dec: object) -> bool:
    """Whether :func:`render_jvp` applies: the 2-D conditioned decoder, with numba available for the compiled pass."""
    from lagsplat.render.rasterize_cpu import numba_available

    return type(dec) is ConditionedGaussians and numba_available()


@torch.no_grad()
def render_jvp(dec: ConditionedGaussians, z: Tensor, dz: Tensor, height: int, width: int) -> tuple[Tensor, Tensor]:
    """The images of ``z [B,d]`` and their derivatives along ``dz [B,d]`` (raw latent units).

    Returns:
        ``(image [B,3,H,W] in [0, 1], tangent [B,3,H,W])``, float32, the tangent zero where the image is clamped.

    Raises:
        ValueError: for another decoder (see :func:`supports_render_jvp`) or shapes that differ.
    """
    from lagsplat.render.rasterize_cpu import rasterize_cpu_jvp

    if type(dec) is not ConditionedGaussians:
        raise ValueError(f"render_jvp renders the 2-D conditioned decoder, got {type(dec).__name__}")
    if z.shape != dz.shape:
        raise ValueError(f"z {tuple(z.shape)} and dz {tuple(dz.shape)} must have one shape")
    g = dec.geometry()
    colors, bg = g.colors, dec.background
    backdrop = dec.backdrop_image(height, width)
    if backdrop is not None:  # the coverage channel, everything over zero (as render)
        colors = torch.cat([colors, colors.new_ones(*colors.shape[:-1], 1)], -1)
        bg = bg.new_zeros(4)
    with fwAD.dual_level():  # the decoder's own conditioning and screen mapping, with the state's tangent
        means, gate, _ = dec.condition(fwAD.make_dual(z.float(), dz.float()), g)
        uv_d, covs, opacities_d, colors = dec.screen(means, gate, g, colors, height, width)
        uv, d_uv = fwAD.unpack_dual(uv_d)
        opacities, d_opacities = fwAD.unpack_dual(opacities_d)
    d_uv = torch.zeros_like(uv) if d_uv is None else d_uv
    d_opacities = torch.zeros_like(opacities) if d_opacities is None else d_opacities
    img, tan = rasterize_cpu_jvp(uv.float(), covs.float(), opacities.float(), colors.float(), d_uv.float(), d_opacities.float(),
                                 height, width, background=bg)  # fmt: skip
    rgb, d_rgb = img[:, :3], tan[:, :3]
    if backdrop is not None:
        rgb = rgb + (1.0 - img[:, 3:4]) * backdrop.to(rgb)[None]
        d_rgb = d_rgb - tan[:, 3:4] * backdrop.to(rgb)[None]
    inside = (rgb > 0.0) & (rgb < 1.0)
    return rgb.clamp(0.0, 1.0), torch.where(inside, d_rgb, torch.zeros_like(d_rgb))
