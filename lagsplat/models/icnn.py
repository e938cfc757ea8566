"""Input-convex network (Amos et al. 2017) and the anchored convex potential (paper §3.3)."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

__all__ = ["ICNN", "ConvexPotential"]


class ICNN(nn.Module):
    """Scalar input-convex network ``g: R^d -> R``.

    ``h_1 = softplus(W_0 x + b_0)``, ``h_{l+1} = softplus(W_l x + softplus(R_l) h_l + b_l)``,
    ``g = softplus(w)^T h_L``: non-negative weights on the hidden path and
    convex, non-decreasing activations make ``g`` convex in ``x``.

    Args:
        d: input dimension.
        hidden: hidden widths (paper App. C: [64, 64]).

    Shapes: ``x [B,d] -> [B]``.
    """

    def __init__(self, d: int, hidden: tuple[int, ...] = (64, 64)) -> None:
        super().__init__()
        self.inp = nn.ModuleList([nn.Linear(d, h) for h in hidden])
        self.rec = nn.ParameterList([nn.Parameter(torch.full((hidden[i + 1], hidden[i]), -3.0)) for i in range(len(hidden) - 1)])
        self.out = nn.Parameter(torch.zeros(hidden[-1]))
        for lin in self.inp:
            nn.init.zeros_(lin.bias)

    def forward(self, x: Tensor) -> Tensor:
        """Evaluate ``g(x)``."""
        h = F.softplus(self.inp[0](x))
        for lin, R in zip(self.inp[1:], self.rec):
            h = F.softplus(lin(x) + h @ F.softplus(R).T)
        return h @ F.softplus(self.out)


class ConvexPotential(nn.Module):
    """Coercive convex potential with a unique minimum at ``q_rest`` (paper §3.3, App. A.2 (A2)).

    ``V(q) = g(q) - g(q*) - grad g(q*)^T (q - q*) + eps/2 |q - q*|^2``, the Bregman
    divergence of an :class:`ICNN` ``g`` anchored at the rest state ``q*``, plus
    the quadratic floor that makes ``V`` strongly convex, hence coercive with
    ``q*`` its only stationary point.

    Args:
        d: latent dimension.
        hidden: ICNN widths.
        eps: quadratic floor (in whitened latent units).
        q_rest: initial rest state ``[d]`` (default 0).
        learn_rest: whether ``q*`` is trained (for clips with no rest frame).

    Shapes: ``q [B,d] -> V [B]``.
    """

    def __init__(
        self, d: int, hidden: tuple[int, ...] = (64, 64), eps: float = 0.01, q_rest: Tensor | None = None, learn_rest: bool = True
    ) -> None:
        super().__init__()
        self.g = ICNN(d, hidden)
        self.eps = float(eps)
        rest = torch.zeros(d) if q_rest is None else torch.as_tensor(q_rest, dtype=torch.float32).clone()
        if learn_rest:
            self.q_rest = nn.Parameter(rest)
        else:
            self.register_buffer("q_rest", rest)

    def forward(self, q: Tensor) -> Tensor:
        """Potential energy ``V(q) >= 0``."""
        # Build the view with grad enabled: made under no_grad it would be cut off
        # from q_rest's graph and the gradient below would fail.
        with torch.enable_grad():
            qr = self.q_rest.unsqueeze(0)
            qr_ = qr if qr.requires_grad else qr.detach().requires_grad_(True)
            g_r = self.g(qr_)
            (grad_r,) = torch.autograd.grad(g_r.sum(), qr_, create_graph=True)
        diff = q - qr
        return self.g(q) - g_r - (diff * grad_r).sum(-1) + 0.5 * self.eps * (diff * diff).sum(-1)
