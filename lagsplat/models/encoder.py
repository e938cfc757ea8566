"""Continuity-preserving CNN encoder (paper §3.2 and App. C, after Zhu et al. 2025)."""

from __future__ import annotations

import torch
from torch import Tensor, nn

__all__ = ["CpAEEncoder", "nonlocal_filter_penalty"]


class CpAEEncoder(nn.Module):
    """Large-filter CNN mapping an image to the latent state ``q``.

    Three ``kernel x kernel`` convolutions (default 12x12) with ``channels``
    output channels each, stride 2, padding ``(kernel - 2) // 2`` and ELU,
    average-pooled to 4x4 and mapped to ``d`` by one linear layer (paper App. C:
    "three convolutions with 12x12 filters, two channels each ... about 2 000
    parameters"). Large filters with few channels keep the encoding Lipschitz
    in the image, so a moving object gives a continuously moving ``q``.

    Args:
        d: latent dimension.
        channels: output channels of the three convolutions.
        kernel: filter size.

    With a reference image (:meth:`set_reference`, a buffer saved with the weights) the convolutions read
    each image's departure from it, ``x - reference``; without one (the paper's encoder) the image itself.

    Shapes:
        input ``[B,3,H,W]`` in [0, 1]; output ``[B,d]`` (raw, unwhitened ``z``).
    """

    def __init__(self, d: int, channels: tuple[int, int, int] = (2, 2, 2), kernel: int = 12) -> None:
        super().__init__()
        pad = (kernel - 2) // 2
        layers: list[nn.Module] = []
        c_in = 3
        for c in channels:
            layers += [nn.Conv2d(c_in, c, kernel, stride=2, padding=pad), nn.ELU()]
            c_in = c
        self.features = nn.Sequential(*layers, nn.AdaptiveAvgPool2d((4, 4)))
        self.head = nn.Linear(c_in * 16, d)
        self.d = d
        self.register_buffer("reference", None)

    def set_reference(self, image: Tensor | None) -> None:
        """From now on encode each image's departure from ``image [3,H,W]`` (in [0, 1], the encoder's input size;
        ``None``: the image itself). The image is copied into the ``reference`` buffer (saved in the state dict)."""
        self.reference = None if image is None else image.detach().clone()

    def forward(self, x: Tensor) -> Tensor:
        """Encode ``x [B,3,H,W]`` to ``z [B,d]``."""
        if x.dim() != 4 or x.shape[1] != 3:
            raise ValueError(f"encoder input must be [B,3,H,W], got {tuple(x.shape)}")
        if self.reference is not None:
            x = x - self.reference
        return self.head(self.features(x).flatten(1))

    def large_kernels(self) -> list[Tensor]:
        """Weights of the large-filter convolutions (for :func:`nonlocal_filter_penalty`)."""
        return [m.weight for m in self.features if isinstance(m, nn.Conv2d)]


def nonlocal_filter_penalty(weights: list[Tensor], sigma: float = 1.0) -> Tensor:
    """Nonlocal smoothness penalty on filter taps, the ``R_nl`` of paper Eq. (5).

    ``sum_w 1/2 sum_ab K_ab (w_a - w_b)^2`` with ``K_ab = exp(-|p_a - p_b|^2 / sigma^2)``
    over the taps ``p`` of each ``J x J`` filter (Zhu et al. 2025). It equals
    ``w^T (diag(K 1) - K) w`` per filter row.

    Args:
        weights: conv weights ``[C_out, C_in, J, J]``.
        sigma: kernel width in taps.

    Returns:
        Scalar penalty.
    """
    total = weights[0].new_zeros(())
    for w in weights:
        J = w.shape[-1]
        ii, jj = torch.meshgrid(torch.arange(J), torch.arange(J), indexing="ij")
        p = torch.stack([ii.flatten(), jj.flatten()], -1).to(w)
        K = torch.exp(-torch.cdist(p, p) ** 2 / sigma**2)
        lap = torch.diag(K.sum(1)) - K
        rows = w.reshape(-1, J * J)
        total = total + torch.einsum("ra,ab,rb->", rows, lap, rows)
    return total
