"""The compositing rule every rasteriser backend follows, and the per-Gaussian quantities it needs.

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
"""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["ALPHA_MIN", "ALPHA_MAX", "EPS2D", "SUPPORT_SIGMA", "prepare_gaussians", "pixel_bounds", "alpha_of"]

ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
EPS2D = 0.3
SUPPORT_SIGMA = 3.0


def prepare_gaussians(means: Tensor, covs: Tensor, opacities: Tensor, colors: Tensor, eps2d: float):
    """Broadcast inputs; return ``(B, K, conic [B,K,3], colors [B,K,C], r2 [B,K], sxx, syy)``: the inverse
    dilated covariance entries ``(a, b, c)``, the support radius^2 (-1: never visible) and the dilated variances.

    Raises:
        ValueError: on inconsistent shapes.
    """
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


def pixel_bounds(means: Tensor, r2: Tensor, sxx: Tensor, syy: Tensor, height: int, width: int):
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


def alpha_of(d2: Tensor, opac: Tensor, r2: Tensor) -> Tensor:
    """Opacity of each (primitive, pixel) pair under the rule: capped at ``ALPHA_MAX``, 0 beyond the support or below ``ALPHA_MIN``."""
    a = torch.clamp(opac * torch.exp(-0.5 * d2), max=ALPHA_MAX)
    keep = (d2 <= r2) & (a >= ALPHA_MIN)
    return torch.where(keep, a, torch.zeros_like(a))
