"""Stage-1 reconstruction loss (paper Eq. 5) and its terms."""

from __future__ import annotations

import math

import torch
from pytorch_msssim import ssim
from torch import Tensor

from lagsplat.models.decoder import ConditionedGaussians

__all__ = ["anisotropy_penalty", "kinematic_penalty", "reconstruction_loss"]


def anisotropy_penalty(decoder: ConditionedGaussians, height: int, width: int, max_ratio: float = 5.0) -> Tensor:
    """Aspect-ratio cap ``R_a`` of paper Eq. (5).

    Mean over primitives of ``max(0, log r - log max_ratio)``, with ``r`` the
    axis ratio ``sqrt(lambda_max / lambda_min)`` of the *marginal* spatial block
    ``Sigma_ss`` in pixel units (so the cap means the same on non-square images).

    Returns:
        Scalar tensor.
    """
    d = decoder.d
    L = decoder.cholesky()
    L_s = L[:, d:, :]  # rows of the spatial coordinates: Sigma_ss = L_s L_s^T
    scale = L.new_tensor([float(width), float(height)])
    S = (L_s @ L_s.transpose(-1, -2)) * scale[None, :, None] * scale[None, None, :]
    a, b, c = S[:, 0, 0], S[:, 0, 1], S[:, 1, 1]
    m = 0.5 * (a + c)
    p = torch.sqrt((0.5 * (a - c)) ** 2 + b * b + 1e-20)
    lam_max, lam_min = m + p, (m - p).clamp_min(1e-8)
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

    SSIM is ``pytorch_msssim.ssim`` with a ``ssim_window`` Gaussian window
    (sigma 1.5, the paper's 7x7), data range 1. The window shrinks to the
    largest odd size that fits very small images.

    Args:
        pred, target: ``[B,3,H,W]`` images in [0, 1].
        decoder: the decoder, for the anisotropy term.

    Returns:
        ``(loss, parts)`` with the scalar loss and the float value of each term.
    """
    H, W = target.shape[-2:]
    win = min(ssim_window, (min(H, W) - 1) | 1)
    l1 = (pred - target).abs().mean()
    s = ssim(pred, target, data_range=1.0, win_size=win, size_average=True)
    an = anisotropy_penalty(decoder, H, W, max_ratio)
    loss = w_l1 * l1 + w_ssim * (1.0 - s) + w_aniso * an
    return loss, {"l1": float(l1.detach()), "ssim": float(s.detach()), "aniso": float(an.detach())}


def kinematic_penalty(decoder, z_std: Tensor) -> Tensor:
    """Minimal-motion prior on the decoder's kinematics (Stage 1, optional).

    ``sum_i alpha_i |J_i diag(z_std)|_F^2 / sum_i alpha_i``: the squared image
    displacement (normalised image units) of each primitive over one standard
    deviation of every latent coordinate, averaged with the opacities. The
    Jacobians ``J_i = Sigma_sq Sigma_qq^-1`` (paper Eq. 2, 9) are fixed by the
    images only where the texture under a primitive changes when it moves; on
    flat regions the reconstruction loss leaves them free, and slow brightness
    changes (exposure, reflections) can be explained by sliding primitives. A
    small weight sets those unconstrained Jacobians to zero, so a force applied
    on static background transports to nothing (paper §3.4, App. A.1), while
    textured moving parts, whose motion the reconstruction pins, keep theirs.

    Args:
        decoder: :class:`~lagsplat.models.decoder.ConditionedGaussians`.
        z_std: ``[d]`` spread of the raw latents (detached), the motion scale.

    Returns:
        Scalar tensor (dimensionless, normalised image units squared).
    """
    g = decoder.geometry()
    Jz = g.J * z_std.reshape(1, 1, -1).clamp_min(1e-3)
    w = g.alpha
    return (w * Jz.pow(2).sum((1, 2))).sum() / w.sum().clamp_min(1e-12)


def static_motion_penalty(motion: Tensor, static: Tensor) -> Tensor:
    """Matter shown on pixels that never change does not move (Stage 1, optional).

    ``motion [B,C,H,W]`` is the decoder's composited motion field at the batch
    states, ``sum_i T_i(p) a_i(p) J_i diag(z_std)`` in pixels (channels: the
    ``2 d`` entries of the Jacobian times the spread of each latent, from
    :meth:`~lagsplat.models.decoder.ConditionedGaussians.render` with
    ``extra``); ``static [H,W]`` marks the pixels whose colour never changes in
    the training frames (:func:`lagsplat.force_checks.motion_masks`). The
    penalty is the mean squared motion over those pixels, in px^2: what a
    force applied there would move (the visible brush of :mod:`lagsplat.force`
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
