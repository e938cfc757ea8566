"""Input-convex networks and the potentials built on them (paper §3.3, App. A.2).

* :class:`ICNN`: scalar input-convex network (Amos et al. 2017).
* :class:`IResNet`: invertible residual map (Behrmann et al. 2019), the
  diffeomorphism of the invex potential.
* :class:`ConvexPotential`: Bregman-anchored ICNN plus a quadratic floor,
  optionally composed with an :class:`IResNet` (the invex potential).
* :class:`ConcaveMap`: the concave chamber-volume map ``nu(q)`` of the
  measured actuation (paper Eq. 6).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

__all__ = ["ICNN", "IResNet", "ConvexPotential", "ConcaveMap", "softplus_slope"]


def softplus_slope(x: Tensor) -> Tensor:
    """``d softplus(x) / dx`` as autograd takes it for :func:`torch.nn.functional.softplus`: ``sigmoid(x)``, exactly 1
    beyond softplus's linear threshold (20)."""
    return torch.where(x > 20.0, torch.ones_like(x), torch.sigmoid(x))


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

    @torch.no_grad()
    def spread_kinks(self, x: Tensor, sharpness: float, seed: int = 0) -> None:
        """Place every input unit's softplus kink inside the data instead of at the origin.

        Unit ``i`` of each input map gets the direction ``a_i`` (``+1`` for ``d = 1``, a random unit vector
        with a non-negative first entry otherwise), a sign ``sigma_i`` alternating over the units, a knot
        ``c_i`` at the ``l_i``-quantile of ``x a_i`` (levels evenly spaced over ``[0.02, 0.98]``), and the
        pre-activation ``sigma_i s (a_i^T x - c_i) / ptp(x a_i)``: a kink of width ``ptp / s`` at ``c_i``. The
        default initialisation puts every kink at ``x = 0`` with unit slope, so the ICNN starts as a
        smooth bowl and a wall (an end stop) far from the rest state is smeared over the whole range.
        Convexity is untouched (the input maps are unconstrained).

        Args:
            x: ``[N,d]`` training states.
            sharpness: ``s > 0``, the kinks' slope in units of the data's range.
            seed: seed of the directions (``d > 1``).

        Raises:
            ValueError: if ``sharpness <= 0``, ``x`` is not ``[N,d]`` or holds fewer than two states.
        """
        d = self.inp[0].in_features
        if sharpness <= 0 or x.ndim != 2 or x.shape[1] != d or len(x) < 2:
            raise ValueError(f"spread_kinks needs sharpness > 0 and [N>=2,{d}] states, got {sharpness} and {tuple(x.shape)}")
        gen = torch.Generator().manual_seed(int(seed))
        x = x.detach().cpu().float()
        for lin in self.inp:
            n = lin.out_features
            a = torch.ones(n, 1) if d == 1 else torch.randn(n, d, generator=gen)
            a = a / a.norm(dim=1, keepdim=True) * torch.where(a[:, :1] < 0, -1.0, 1.0)
            p = x @ a.T  # [N,n]
            levels = torch.linspace(0.02, 0.98, n)
            c = torch.stack([torch.quantile(p[:, i], levels[i]) for i in range(n)])
            sign = torch.where(torch.arange(n) % 2 == 0, 1.0, -1.0)
            scale = sign * sharpness / (p.max(0).values - p.min(0).values).clamp_min(1e-6)
            lin.weight.copy_((scale[:, None] * a).to(lin.weight))
            lin.bias.copy_((-scale * c).to(lin.bias))

    def forward(self, x: Tensor) -> Tensor:
        """Evaluate ``g(x)``."""
        h = F.softplus(self.inp[0](x))
        for lin, R in zip(self.inp[1:], self.rec):
            h = F.softplus(lin(x) + h @ F.softplus(R).T)
        return h @ F.softplus(self.out)

    def gradient(self, x: Tensor) -> Tensor:
        """``grad g(x) [B,d]`` by an explicit backward pass through the layers (``softplus' = sigmoid``).

        Built of first-order operations, so it is differentiable in ``x`` and the weights without a second
        autograd pass; equal to ``torch.autograd.grad`` of :meth:`forward` (tests/test_inertia_jacobian.py).
        """
        R = [F.softplus(r) for r in self.rec]
        pre = [self.inp[0](x)]
        for lin, R_l in zip(self.inp[1:], R):
            pre.append(lin(x) + F.softplus(pre[-1]) @ R_l.T)
        delta = F.softplus(self.out) * softplus_slope(pre[-1])
        grad = delta @ self.inp[-1].weight
        for layer in range(len(pre) - 2, -1, -1):
            delta = (delta @ R[layer]) * softplus_slope(pre[layer])
            grad = grad + delta @ self.inp[layer].weight
        return grad


def spectral_norm_estimate(w: Tensor) -> Tensor:
    """Largest singular value of a matrix (exact, differentiable)."""
    return torch.linalg.matrix_norm(w, ord=2)


class IResNet(nn.Module):
    """Invertible residual map ``phi = (id + g_B) o ... o (id + g_1)`` (i-ResNet).

    Each block is ``g(x) = W_2 elu(W_1 x + b_1) + b_2`` with the weights rescaled
    at every call to ``|W_1|_2 <= 1`` and ``|W_2|_2 <= lip`` (exact spectral
    norms, not a power-iteration estimate), so ``Lip(g) <= lip < 1``. Hence
    each block, and ``phi``, is a bi-Lipschitz diffeomorphism of ``R^d``:
    ``(1 - lip)^B |x - y| <= |phi(x) - phi(y)| <= (1 + lip)^B |x - y|`` and its
    Jacobian ``I + J_g`` is invertible everywhere (paper §3.3 "Potential",
    App. C: 2 blocks, width 64, Lipschitz cap 0.9).

    Shapes: ``x [B,d] -> [B,d]``. Starts near the identity (last layer 1e-2 scale).
    """

    def __init__(self, d: int, blocks: int = 2, width: int = 64, lip: float = 0.9) -> None:
        super().__init__()
        if not 0.0 < lip < 1.0:
            raise ValueError(f"IResNet Lipschitz cap must be in (0, 1), got {lip}")
        self.lip = float(lip)
        self.l1 = nn.ModuleList([nn.Linear(d, width) for _ in range(blocks)])
        self.l2 = nn.ModuleList([nn.Linear(width, d) for _ in range(blocks)])
        for lin in self.l2:
            with torch.no_grad():
                lin.weight.mul_(1e-2)
                lin.bias.zero_()

    def _blocks(self) -> list[tuple[Tensor, Tensor, Tensor, Tensor]]:
        """Each block's ``(W_1, b_1, W_2, b_2)`` with the weights rescaled to their spectral caps."""
        return [(a.weight / spectral_norm_estimate(a.weight).clamp_min(1.0), a.bias,
                 b.weight * (self.lip / spectral_norm_estimate(b.weight).clamp_min(self.lip)), b.bias)
                for a, b in zip(self.l1, self.l2)]  # fmt: skip

    def forward(self, x: Tensor) -> Tensor:
        """``phi(x)``."""
        return self.forward_saved(x)[0]

    def forward_saved(self, x: Tensor) -> tuple[Tensor, tuple]:
        """``(phi(x), saved)``: ``saved`` is what :meth:`pullback` needs (the rescaled weights, each block's
        pre-activation)."""
        blocks, pre = self._blocks(), []
        for w1, b1, w2, b2 in blocks:
            pre.append(F.linear(x, w1, b1))
            x = x + F.linear(F.elu(pre[-1]), w2, b2)
        return x, (blocks, pre)

    @staticmethod
    def pullback(saved: tuple, v: Tensor) -> Tensor:
        """``Dphi(x)^T v [B,d]`` at the ``x`` of :meth:`forward_saved`, by an explicit backward pass through the
        blocks (``I + W_2 diag(elu'(W_1 x + b_1)) W_1`` each); first-order differentiable."""
        blocks, pre = saved
        for (w1, _, w2, _), p in zip(reversed(blocks), reversed(pre)):
            v = v + ((v @ w2) * torch.where(p > 0, torch.ones_like(p), torch.exp(p))) @ w1
        return v

    @torch.no_grad()
    def inverse(self, y: Tensor, iters: int = 100, tol: float = 1e-7) -> Tensor:
        """``phi^-1(y)`` by the contraction ``x <- y_b - g(x)`` block by block (converges as ``lip^n``)."""
        for a, b in reversed(list(zip(self.l1, self.l2))):
            w1 = a.weight / spectral_norm_estimate(a.weight).clamp_min(1.0)
            w2 = b.weight * (self.lip / spectral_norm_estimate(b.weight).clamp_min(self.lip))
            x = y.clone()
            for _ in range(iters):
                x_new = y - F.linear(F.elu(F.linear(x, w1, a.bias)), w2, b.bias)
                done = (x_new - x).abs().max() < tol
                x = x_new
                if done:
                    break
            y = x
        return y


class ConvexPotential(nn.Module):
    """Coercive potential with a unique minimum at ``q_rest`` (paper §3.3, App. A.2 (A2)).

    Convex form: ``V(q) = g(q) - g(q*) - grad g(q*)^T (q - q*) + eps/2 |q - q*|^2``,
    the Bregman divergence of an :class:`ICNN` ``g`` anchored at the rest state
    ``q*``, plus the quadratic floor that makes ``V`` strongly convex, hence
    coercive with ``q*`` its only stationary point.

    Invex form (``invex=True``): the same expression evaluated at ``phi(q)`` and
    ``phi(q*)`` with ``phi`` an :class:`IResNet`. ``grad V = Dphi^T grad V_cvx``
    with ``Dphi`` invertible, so ``q*`` is still the only stationary point and
    ``V`` is coercive (``phi`` is bi-Lipschitz), while its level sets need not
    be convex (Sapkota & Bhattacharya 2021).

    Args:
        d: latent dimension.
        hidden: ICNN widths.
        eps: quadratic floor (in whitened latent units).
        q_rest: initial rest state ``[d]`` (default 0).
        learn_rest: whether ``q*`` is trained (for clips with no rest frame).
        invex: compose with an i-ResNet.
        iresnet_blocks, iresnet_width, iresnet_lip: its settings (App. C: 2, 64, 0.9).

    Shapes: ``q [B,d] -> V [B]``.
    """

    def __init__(
        self,
        d: int,
        hidden: tuple[int, ...] = (64, 64),
        eps: float = 0.01,
        q_rest: Tensor | None = None,
        learn_rest: bool = True,
        invex: bool = False,
        iresnet_blocks: int = 2,
        iresnet_width: int = 64,
        iresnet_lip: float = 0.9,
    ) -> None:
        super().__init__()
        self.g = ICNN(d, hidden)
        self.phi = IResNet(d, iresnet_blocks, iresnet_width, iresnet_lip) if invex else None
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
            if self.phi is not None:
                qr = self.phi(qr)
            qr_ = qr if qr.requires_grad else qr.detach().requires_grad_(True)
            g_r = self.g(qr_)
            (grad_r,) = torch.autograd.grad(g_r.sum(), qr_, create_graph=True)
        y = q if self.phi is None else self.phi(q)
        diff = y - qr
        return self.g(y) - g_r - (diff * grad_r).sum(-1) + 0.5 * self.eps * (diff * diff).sum(-1)

    def gradient(self, q: Tensor) -> Tensor:
        """``grad V(q) [B,d]`` in closed form, first-order differentiable: ``grad g(y) - grad g(y*) + eps (y - y*)``
        at ``y = q`` (convex form, :meth:`ICNN.gradient`) or pulled back through the i-ResNet,
        ``Dphi(q)^T (...)`` at ``y = phi(q)`` (invex form, :meth:`IResNet.pullback`)."""
        x = torch.cat([q, self.q_rest.unsqueeze(0).to(q.dtype)])  # the rest state rides along as one more row
        y, saved = (x, None) if self.phi is None else self.phi.forward_saved(x)
        g = self.g.gradient(y)
        v = g[:-1] - g[-1:] + self.eps * (y[:-1] - y[-1:])
        if saved is None:
            return v
        blocks, pre = saved
        return self.phi.pullback((blocks, [p[:-1] for p in pre]), v)


class ConcaveMap(nn.Module):
    """Concave chamber-volume map ``nu: R^d -> R^{n_u}`` (paper Eq. 6).

    ``nu_j(q) = a_j^T q - g_j(q) + g_j(0)`` with ``g_j`` an :class:`ICNN` (one head
    per channel), concave by construction, so the loaded potential
    ``V - P^T nu`` stays coercive and, with the convex ``V``, strongly convex
    for every ``P >= 0``. ``a`` starts small and random (seeded by the caller),
    ``g_j`` at its default initialisation.

    Shapes: ``q [B,d] -> nu [B,n_u]``; :meth:`force` gives ``f_P = b(q)^T P``
    with ``b = d nu / d q`` ``[B,n_u,d]``.
    """

    def __init__(self, d: int, n_u: int, hidden: tuple[int, ...] = (32, 32), init_scale: float = 0.1) -> None:
        super().__init__()
        self.d, self.n_u = int(d), int(n_u)
        self.a = nn.Parameter(init_scale * torch.randn(n_u, d))
        self.heads = nn.ModuleList([ICNN(d, hidden) for _ in range(n_u)])

    def forward(self, q: Tensor) -> Tensor:
        """``nu(q) [B,n_u]``."""
        zero = q.new_zeros(1, self.d)
        g = torch.stack([h(q) - h(zero) for h in self.heads], -1)
        return q @ self.a.T - g

    def nonlinearity(self, q: Tensor) -> Tensor:
        """Mean over the batch of ``|grad_q sum_j g_j(q)|^2``: how far the map departs from a linear
        one (``b(q)`` constant, all channels at equal pressure), zero for a linear map. A prior on it
        keeps the restoring force in ``V`` where the pressures never vanish in training
        (``Stage2Config.w_actuation_linear``). Differentiable (graph kept).

        Shapes: ``q [B,d] -> []``.
        """
        grad = sum(h.gradient(q.detach()) for h in self.heads)
        return (grad**2).sum(-1).mean()

    def force(self, q: Tensor, P: Tensor, create_graph: bool = False) -> Tensor:
        """Generalized actuation force ``f_P = b(q)^T P = sum_j P_j (a_j - grad g_j(q))`` ``[B,d]`` for pressures
        ``P [B,n_u]``, in closed form (:meth:`ICNN.gradient`); differentiable with ``create_graph``, detached otherwise."""
        P = P.to(q.dtype)
        f = P @ self.a - sum(P[:, j : j + 1] * h.gradient(q) for j, h in enumerate(self.heads))
        return f if create_graph else f.detach()
