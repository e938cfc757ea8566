"""Where the decoder spends its Gaussians: motion-aware placement and the split of an overloaded Gaussian.

A small moving object over a large, textured, static scene is cheap to leave
out under the photometric loss: most primitives start (and are recycled) on
the background. Two moves of paper App. C keep primitives on what moves:

* :func:`placement_probability`: where new primitives are drawn, from the
  image gradient (the reference's "smart init") and, as well, the temporal
  standard deviation of the training frames, so that the moving object gets
  primitives in proportion to how much it changes, not to its area;
* :func:`split_overloaded`: the paper's other recycling move, missing from the
  reference code: an overloaded alive Gaussian is split in two along the
  principal eigenvector of its full ``(n + d)``-D covariance (in units of the
  initial extents). A primitive stretched along the latent axis (one Gaussian
  drawing the object over the whole range of ``q``) becomes two, each over
  half the range with its own linear motion, so that a rotation or any curved
  path is drawn piece by piece.
"""

from __future__ import annotations

import torch
from torch import Tensor

from lagsplat.models.decoder import DIAG_FLOOR, ConditionedGaussians, inverse_softplus

__all__ = ["placement_probability", "overload", "split_overloaded"]


def placement_probability(frame: Tensor, motion_std: Tensor | None = None, w_motion: float = 1.0, backdrop: Tensor | None = None) -> Tensor:
    """Probability ``[H*W]`` (unnormalised) of placing a primitive at each pixel.

    ``0.8 |grad I| / max + 0.2`` (the reference's edge-favouring draw), plus
    ``w_motion * std / max`` where ``motion_std`` is the per-pixel temporal
    standard deviation of the training frames (``None`` or ``w_motion = 0``: the
    reference draw). With a static layer (``backdrop``) the edges are its to draw:
    ``|frame - backdrop| / max + 0.05`` (channel mean) replaces the edge term.

    Args:
        frame: ``[3,H,W]`` image in [0, 1].
        motion_std: ``[H,W]`` temporal standard deviation, or ``None``.
        w_motion: weight of the motion term.
        backdrop: ``[3,H,W]`` the decoder's static layer, or ``None``.
    """
    if backdrop is not None:  # the layer draws the edges: where the frame departs from it
        dep = (frame - backdrop.to(frame)).abs().mean(0).flatten()
        prob = dep / dep.max().clamp_min(1e-12) + 0.05
    else:
        gray = frame.mean(0)
        gx = torch.zeros_like(gray)
        gy = torch.zeros_like(gray)
        gx[:, :-1] = gray[:, 1:] - gray[:, :-1]
        gy[:-1, :] = gray[1:, :] - gray[:-1, :]
        mag = torch.sqrt(gx**2 + gy**2).flatten()
        prob = 0.8 * mag / mag.max().clamp_min(1e-12) + 0.2
    if motion_std is not None and w_motion > 0:
        m = motion_std.flatten().to(prob)
        prob = prob + w_motion * m / m.max().clamp_min(1e-12)
    return prob


def _scales(dec: ConditionedGaussians, z_std: Tensor, sigma_xy: float) -> Tensor:
    """``[n+d]`` units of the (q, s) coordinates: the latent spread and the initial spatial extent
    (``[2]``, spatial only, for a decoder without a latent block, ``dec.latent_block = 0``)."""
    z_std = z_std[: dec.latent_block]
    return torch.cat([z_std.clamp_min(1e-3), torch.full((dec.n_space,), float(sigma_xy))]).to(dec.mu_raw)


@torch.no_grad()
def overload(dec: ConditionedGaussians, z_std: Tensor, sigma_xy: float) -> tuple[Tensor, Tensor]:
    """How overloaded each primitive is: ``(score [K], principal eigenvector [K,n+d])``.

    The score is ``alpha * lambda_max`` of the covariance in units of
    :func:`_scales` (``D^-1 Sigma D^-1``): an opaque primitive stretched far
    beyond its initial extent, in the image or along ``q``. The eigenvector is
    returned in the raw (q, s) coordinates, scaled to one standard deviation.
    """
    D = _scales(dec, z_std, sigma_xy)
    S = dec.covariance() / (D[None, :, None] * D[None, None, :])
    lam, V = torch.linalg.eigh(S)
    top, v = lam[:, -1].clamp_min(0.0), V[:, :, -1]
    alpha = torch.sigmoid(dec.logit_alpha)
    return alpha * top, v * D[None] * top.sqrt()[:, None]


@torch.no_grad()
def split_overloaded(dec: ConditionedGaussians, dead: Tensor, z_std: Tensor, sigma_xy: float) -> tuple[Tensor, Tensor]:
    """Move the primitives flagged in ``dead`` onto the most overloaded alive ones, splitting each in two.

    For each dead primitive, one alive primitive (most overloaded first,
    :func:`overload`) with mean ``mu`` and principal axis ``e`` (one standard
    deviation along the top eigenvector of its full covariance) becomes the pair
    ``mu -+ e / 2`` (the positions pass through the decoder's sigmoid
    parameterisation), both with the covariance ``Sigma - 3/4 e e^T`` (the
    variance along ``e`` quartered), and the parent's colour and opacity.

    Args:
        dec: the decoder (changed in place).
        dead: ``[K]`` bool, the primitives to reuse.
        z_std: ``[d]`` spread of the training latents (the latent unit).
        sigma_xy: initial spatial extent, normalised image units (the spatial unit).

    Returns:
        ``(children, parents)``, ``[K]`` bool each: the dead primitives used (fewer than
        ``dead`` when fewer alive ones are overloaded) and the split parents (their
        optimiser moments are stale too).
    """
    idx_dead = torch.nonzero(dead).flatten()
    score, e = overload(dec, z_std, sigma_xy)
    score = torch.where(dead, torch.full_like(score, -1.0), score)
    n = min(len(idx_dead), int((score > 0).sum()))
    parents = torch.argsort(score, descending=True)[:n]
    children = idx_dead[:n]
    d = dec.latent_block
    cov = dec.covariance()[parents]
    half = 0.5 * e[parents]  # (q, s) order
    new_cov = cov - 0.75 * (2 * half)[:, :, None] * (2 * half)[:, None, :]
    n_dim = dec.n_space + d
    new_cov = 0.5 * (new_cov + new_cov.transpose(1, 2)) + 1e-9 * torch.eye(n_dim, dtype=cov.dtype)
    L = torch.linalg.cholesky(new_cov)
    raw = L[:, dec.tril_i, dec.tril_j]
    diag = dec.tril_i == dec.tril_j
    raw[:, diag] = inverse_softplus((raw[:, diag] - DIAG_FLOOR).clamp_min(1e-6))
    mu_s = dec.spatial_mean(dec.mu_raw[parents])
    for sign, rows in ((1.0, children), (-1.0, parents)):
        dec.mu_q[rows] = dec.mu_q[parents] + sign * half[:, :d]
        dec.mu_raw[rows] = dec.spatial_raw(mu_s + sign * half[:, d:])
        dec.L_raw[rows] = raw
    dec.logit_color[children] = dec.logit_color[parents]
    dec.logit_alpha[children] = dec.logit_alpha[parents]
    used, split = torch.zeros_like(dead), torch.zeros_like(dead)
    used[children], split[parents] = True, True
    return used, split
