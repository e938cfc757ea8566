"""Stage-1 reconstruction loss (paper Eq. 5) and its terms."""

from __future__ import annotations

import functools
import math

import torch
from torch import Tensor

from lagsplat.models.decoder import ConditionedGaussians

__all__ = [
    "temporal_curvature_penalty",
    "anisotropy_penalty",
    "reconstruction_loss",
    "ssim",
    "static_motion_penalty",
]


@functools.lru_cache(maxsize=32)
def _gaussian_band(n: int, win: int, sigma: float, dtype: torch.dtype, device: torch.device) -> Tensor:
    """``[n - win + 1, n]`` matrix whose rows are the normalised 1-D Gaussian window at each valid offset
    (identity when the window does not fit, ``n < win``)."""
    if n < win:
        return torch.eye(n, dtype=dtype, device=device)
    x = torch.arange(win, dtype=torch.float32) - win // 2
    g = torch.exp(-(x**2) / (2.0 * sigma**2))
    g = g / g.sum()
    band = torch.zeros(n - win + 1, n)
    rows = torch.arange(n - win + 1)
    for k in range(win):
        band[rows, rows + k] = g[k]
    return band.to(dtype=dtype, device=device)


def ssim(pred: Tensor, target: Tensor, win_size: int = 7, sigma: float = 1.5, data_range: float = 1.0) -> Tensor:
    """Mean structural similarity of two image batches (Wang et al., IEEE TIP 2004), differentiable in ``pred``.

    The definition of ``pytorch_msssim.ssim`` (Gaussian window of ``win_size``
    taps and std ``sigma``, applied separably without padding and skipped
    along an axis shorter than the window; ``K = (0.01, 0.03)``; mean over
    pixels, channels and the batch), to which the tests compare it. The
    separable filter is two matrix products with banded Gaussian matrices on
    the whole batch and all five statistics at once, instead of ten grouped
    convolutions: on the CPU the convolutions' backward pass cost more than
    the rasteriser's in a Stage-1 step.

    Args:
        pred, target: ``[B,C,H,W]`` images with values in ``[0, data_range]``.
        win_size: odd window size in pixels.
        sigma: window standard deviation in pixels.

    Returns:
        Scalar tensor.

    Raises:
        ValueError: on different shapes or an even window.
    """
    if pred.shape != target.shape or pred.dim() != 4:
        raise ValueError(f"ssim needs two [B,C,H,W] tensors of one shape, got {tuple(pred.shape)} and {tuple(target.shape)}")
    if win_size % 2 != 1:
        raise ValueError(f"ssim window must be odd, got {win_size}")
    H, W = pred.shape[-2:]
    gh = _gaussian_band(H, win_size, float(sigma), pred.dtype, pred.device)
    gw = _gaussian_band(W, win_size, float(sigma), pred.dtype, pred.device)
    blur = lambda s: gh @ s @ gw.T  # noqa: E731  [..., H, W] -> [..., H', W']
    target = target.to(pred.dtype)
    with torch.no_grad():
        mu2, e22 = blur(torch.stack([target, target * target]))
    mu1, e11, e12 = blur(torch.stack([pred, pred * pred, pred * target]))
    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2
    mu11, mu22, mu12 = mu1 * mu1, mu2 * mu2, mu1 * mu2
    cs = (2.0 * (e12 - mu12) + c2) / ((e11 - mu11) + (e22 - mu22) + c2)
    return (((2.0 * mu12 + c1) / (mu11 + mu22 + c1)) * cs).mean()


def anisotropy_penalty(decoder: ConditionedGaussians, height: int, width: int, max_ratio: float = 5.0) -> Tensor:
    """Aspect-ratio cap ``R_a`` of paper Eq. (5).

    Mean over primitives of ``max(0, log r - log max_ratio)``, with ``r`` the
    axis ratio ``sqrt(lambda_max / lambda_min)`` of the *marginal* spatial block
    ``Sigma_ss`` in pixel units (so the cap means the same on non-square images); for 3-D primitives
    (world units, :mod:`lagsplat.models.decoder3d`) the ratio of the largest to the smallest of the three axes.

    Returns:
        Scalar tensor.
    """
    d = decoder.latent_block  # 0 for the deformation decoder: its Cholesky factor is the spatial one
    L = decoder.cholesky()
    L_s = L[:, d:, :]  # rows of the spatial coordinates: Sigma_ss = L_s L_s^T
    S = L_s @ L_s.transpose(-1, -2)
    if S.shape[-1] == 2:
        scale = L.new_tensor([float(width), float(height)])
        S = S * scale[None, :, None] * scale[None, None, :]
        a, b, c = S[:, 0, 0], S[:, 0, 1], S[:, 1, 1]
        m = 0.5 * (a + c)
        p = torch.sqrt((0.5 * (a - c)) ** 2 + b * b + 1e-20)
        lam_max, lam_min = m + p, (m - p).clamp_min(1e-8)
    else:
        lam = torch.linalg.eigvalsh(S)
        lam_max, lam_min = lam[:, -1], lam[:, 0].clamp_min(1e-12)
    log_r = 0.5 * torch.log(lam_max / lam_min)
    return torch.relu(log_r - math.log(max_ratio)).mean()


def reconstruction_loss(
    pred: Tensor,
    target: Tensor,
    decoder: ConditionedGaussians,
    w_l1: float = 0.08,
    w_ssim: float = 0.02,
    w_aniso: float = 0.01,
    ssim_window: int = 7,
    max_ratio: float = 5.0,
) -> tuple[Tensor, dict[str, float]]:
    """``w_l1 L1 + w_ssim (1 - SSIM) + w_aniso R_a`` (paper Eq. 5, weights of App. C).

    SSIM is :func:`ssim` with a ``ssim_window`` Gaussian window (sigma 1.5,
    the paper's 7x7), data range 1. The window shrinks to the largest odd
    size that fits very small images.

    Args:
        pred, target: ``[B,3,H,W]`` images in [0, 1].
        decoder: the decoder, for the anisotropy term.

    Returns:
        ``(loss, parts)`` with the scalar loss and the float value of each term.
    """
    H, W = target.shape[-2:]
    win = min(ssim_window, (min(H, W) - 1) | 1)
    l1 = (pred - target).abs().mean()
    s = ssim(pred, target, win_size=win)
    an = anisotropy_penalty(decoder, H, W, max_ratio)
    loss = w_l1 * l1 + w_ssim * (1.0 - s) + w_aniso * an
    return loss, {"l1": float(l1.detach()), "ssim": float(s.detach()), "aniso": float(an.detach())}


def static_motion_penalty(motion: Tensor, static: Tensor) -> Tensor:
    """Matter shown on pixels that never change does not move (Stage 1, optional).

    ``motion [B,C,H,W]`` is the decoder's composited motion field at the batch
    states, ``sum_i T_i(p) a_i(p) J_i diag(z_std)`` in pixels (channels: the
    ``2 d`` entries of the Jacobian times the spread of each latent, from
    :meth:`~lagsplat.models.decoder.ConditionedGaussians.render` with
    ``extra``); ``static [H,W]`` marks the pixels whose colour never changes in
    the training frames (:func:`lagsplat.motion.motion_masks`). The
    penalty is the mean squared motion over those pixels, in px^2: what a
    force applied there would move (the visible brush of :mod:`lagsplat.forces.transport`
    pulls back exactly this field, paper Eq. 9), which paper §4.5 requires to
    vanish on background. The reconstruction loss alone leaves it free
    wherever a primitive that moves with the object reaches over static
    texture (a large or elongated footprint straddling the object's edge) or
    slides over flat colour.

    Returns:
        Scalar tensor, px^2 (zero when no pixel is static).
    """
    if not bool(static.any()):
        return motion.new_zeros(())
    return motion.pow(2).sum(1)[:, static].mean()


def temporal_curvature_penalty(z3: Tensor, z_batch: Tensor) -> Tensor:
    """Second difference of the encodings of consecutive frames, relative to the spread of the batch's encodings.

    ``mean |z_{t+1} - 2 z_t + z_{t-1}|^2 / mean var(z_batch)``: small for a chart along
    which the object moves smoothly (about ``(2 pi / N)^4`` for an oscillation sampled at
    ``N`` frames per period), large where the encoder tears the chart (neighbouring
    frames sent far apart). Divided by the spread of the batch's encodings (with its
    gradient), the penalty is scale-free: shrinking the chart does not lower it, and
    its gradient spreads the chart apart as it smooths it.

    Args:
        z3: ``[3, n, d]`` encodings of frames ``t - 1``, ``t``, ``t + 1`` for ``n`` triplets.
        z_batch: ``[B, d]`` encodings of the batch, ``B >= 2``.

    Returns:
        Scalar tensor.
    """
    d2 = z3[2] - 2.0 * z3[1] + z3[0]
    spread = z_batch.var(0).mean().clamp_min(1e-8) if len(z_batch) > 1 else torch.ones((), device=z3.device)
    return (d2**2).sum(-1).mean() / spread
