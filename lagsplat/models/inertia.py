"""Position-dependent inertia fields of the Lagrangian (paper §3.3 "Inertia", Eq. 7).

:class:`CholeskyField`: a learned SPD mass matrix ``M(q) = L(q) L(q)^T + eps I``
(``stage2.mass=learned``); :class:`DecoderInertia`: the parameter-free inertia
read off the frozen Stage-1 decoder (``stage2.mass=decoder``). Used by
:class:`lagsplat.models.lagrangian.Lagrangian`.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from lagsplat.models.decoder import GATE_CLAMP, latent_gate, tril_inverse
from lagsplat.models.icnn import softplus_slope

__all__ = ["CholeskyField", "DecoderInertia"]


class CholeskyField(nn.Module):
    """``q -> L(q) L(q)^T``: an SPD-matrix field from an MLP Cholesky factor.

    MLP ``d -> hidden -> d(d+1)/2`` (ELU), softplus on the diagonal. The last
    layer starts at zero weight with diagonal bias ``softplus^-1(sqrt(init))``,
    so the field starts constant at ``init * I``.

    Shapes: ``q [B,d] -> [B,d,d]``.
    """

    def __init__(self, d: int, hidden: tuple[int, ...] = (64, 64), init: float = 0.2) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        w = d
        for h in hidden:
            layers += [nn.Linear(w, h), nn.ELU()]
            w = h
        last = nn.Linear(w, d * (d + 1) // 2)
        nn.init.zeros_(last.weight)
        self.d = d
        ii, jj = torch.tril_indices(d, d)
        self.register_buffer("ii", ii, persistent=False)
        self.register_buffer("jj", jj, persistent=False)
        with torch.no_grad():
            last.bias.zero_()
            s = torch.tensor(math.sqrt(init))
            last.bias[ii == jj] = s + torch.log(-torch.expm1(-s))
        self.net = nn.Sequential(*layers, last)

    def forward(self, q: Tensor) -> Tensor:
        """SPD matrix ``L L^T`` at each ``q``."""
        raw = self.net(q)
        diag = self.ii == self.jj
        raw = torch.where(diag, F.softplus(raw), raw)
        L = raw.new_zeros(q.shape[0], self.d, self.d)
        L[:, self.ii, self.jj] = raw
        return L @ L.transpose(-1, -2)

    def value_and_jacobian(self, q: Tensor) -> tuple[Tensor, Tensor]:
        """``(S, dS)``: the field ``S(q) [B,d,d]`` and its derivative ``dS [B,d,d,d]``, ``dS[b,i,j,k] = dS_ij / dq_k``.

        Forward-mode through the MLP (one tangent per coordinate, no second autograd pass), so the
        result is differentiable with ordinary first-order autograd; equal to ``torch.autograd``'s
        Jacobian of :meth:`forward` (tests/test_inertia_jacobian.py).
        """
        B, d = q.shape
        x = q
        dx = torch.eye(d, dtype=q.dtype, device=q.device).expand(B, d, d)  # dx[b, i, k] = dx_i / dq_k
        for layer in self.net:
            if isinstance(layer, nn.Linear):
                x, dx = layer(x), torch.einsum("hi,bik->bhk", layer.weight, dx)
            else:  # ELU (alpha 1): elu'(z) = 1 for z > 0, elu(z) + 1 otherwise
                y = layer(x)
                dx = dx * torch.where(x > 0, torch.ones_like(y), y + 1.0).unsqueeze(-1)
                x = y
        diag = self.ii == self.jj
        draw = torch.where(diag[:, None], softplus_slope(x).unsqueeze(-1) * dx, dx)
        raw = torch.where(diag, F.softplus(x), x)
        L = raw.new_zeros(B, d, d)
        L[:, self.ii, self.jj] = raw
        dL = raw.new_zeros(B, d, d, d)
        dL[:, self.ii, self.jj] = draw
        LdLt = torch.einsum("bim,bjmk->bijk", L, dL)
        return L @ L.transpose(-1, -2), LdLt + LdLt.transpose(1, 2)


class DecoderInertia(nn.Module):
    """Parameter-free inertia pulled back through the decoder (paper Eq. 7, App. A.1).

    ``M_hat(q) = sum_i w_hat_i(q) J_i^T J_i / s``, with ``J_i [2,d]`` the constant
    Jacobian of primitive ``i``'s conditioned mean with respect to the
    *whitened* chart coordinate, in pixels, ``w_hat_i(q)`` its latent opacity
    (paper Eq. 4) normalised over primitives, and ``s`` the mean eigenvalue of
    the sum at the chart origin (so ``M_hat(0)`` has trace ``d``; the mass
    ``m`` of Eq. 7 is the model's ``exp(s_M)``, fixed from the observed
    frequency). Everything is a frozen buffer: no learned parameter.

    Built from a trained decoder with :meth:`from_decoder`; the empty
    constructor (shapes only) is for loading a checkpoint.

    Shapes: ``q [B,d] -> [B,d,d]``.
    """

    def __init__(self, n_gaussians: int, d: int) -> None:
        super().__init__()
        K = int(n_gaussians)
        self.register_buffer("J", torch.zeros(K, 2, d))
        self.register_buffer("mu_q", torch.zeros(K, d))
        self.register_buffer("L_qq", torch.eye(d).expand(K, d, d).clone())
        self.register_buffer("alpha", torch.ones(K))
        self.register_buffer("W_inv", torch.eye(d))
        self.register_buffer("mean", torch.zeros(d))
        self.register_buffer("scale", torch.ones(()))

    @classmethod
    @torch.no_grad()
    def from_decoder(cls, decoder: nn.Module, W_inv: Tensor, mean: Tensor, height: int, width: int) -> "DecoderInertia":
        """Freeze the geometry of a :class:`~lagsplat.models.decoder.ConditionedGaussians`.

        Args:
            decoder: the trained Stage-1 decoder.
            W_inv, mean: the chart's de-whitening, ``z = q @ W_inv + mean`` (``[d,d]``, ``[d]``).
            height, width: training resolution (pixels), the units of ``J``.
        """
        g = decoder.geometry()
        K, d = g.mu_q.shape
        out = cls(K, d)
        W_inv = torch.as_tensor(W_inv, dtype=torch.float32)
        out.J.copy_(decoder.chart_kinematics(W_inv, mean, height, width)[1])
        out.mu_q.copy_(g.mu_q)
        out.L_qq.copy_(g.L_qq)
        out.alpha.copy_(g.alpha)
        out.W_inv.copy_(W_inv)
        out.mean.copy_(torch.as_tensor(mean, dtype=torch.float32))
        M0 = out._raw(torch.zeros(1, d))[0]
        out.scale.fill_(float(torch.linalg.eigvalsh(M0).mean().clamp_min(1e-12)))
        return out

    def presence(self, q: Tensor) -> Tensor:
        """``w_hat_i(q) [B,K]``, summing to 1 (latent opacity, paper Eq. 4, normalised)."""
        w = self.alpha[None] * latent_gate(q @ self.W_inv + self.mean, self.mu_q, self.L_qq)
        return w / w.sum(-1, keepdim=True).clamp_min(1e-12)

    def _JtJ(self) -> Tensor:
        """``J_i^T J_i [K,d,d]`` of every primitive."""
        return torch.einsum("kai,kaj->kij", self.J, self.J)

    def _raw(self, q: Tensor) -> Tensor:
        return torch.einsum("bk,kij->bij", self.presence(q), self._JtJ())

    def forward(self, q: Tensor) -> Tensor:
        """``M_hat(q) [B,d,d]`` (before the floor and the mass ``m``)."""
        return self._raw(q) / self.scale

    def value_and_jacobian(self, q: Tensor) -> tuple[Tensor, Tensor]:
        """``(M_hat, dM_hat)``: ``M_hat(q) [B,d,d]`` and ``dM_hat [B,d,d,d]``, ``dM_hat[b,i,j,k] = dM_hat_ij / dq_k``.

        Closed form of the gate's derivative (paper Eq. 4): ``dw_i / dq = -w_i (L_i^-T y_i)^T W_inv^T`` where
        the Mahalanobis distance is below the gate's clamp (0 beyond it), then the normalisation's quotient
        rule. Equal to ``torch.autograd``'s Jacobian of :meth:`forward` (tests/test_inertia_jacobian.py).
        """
        diff = (q @ self.W_inv + self.mean)[:, None, :] - self.mu_q[None]
        L_inv = tril_inverse(self.L_qq)
        y = torch.einsum("kij,bkj->bki", L_inv, diff)
        r2 = (y * y).sum(-1)
        w = self.alpha[None] * torch.exp(-0.5 * r2.clamp(max=GATE_CLAMP))  # [B,K]
        g_z = torch.einsum("kji,bkj->bki", L_inv, y)  # d(r2/2)/dz, [B,K,d]
        dw = -(w * (r2 < GATE_CLAMP)).unsqueeze(-1) * (g_z @ self.W_inv.T)  # dw_i/dq, [B,K,d]
        total = w.sum(-1, keepdim=True).clamp_min(1e-12)
        w_hat = w / total
        dw_hat = (dw - w_hat.unsqueeze(-1) * dw.sum(1, keepdim=True)) / total.unsqueeze(-1)
        JtJ = self._JtJ()
        return (torch.einsum("bk,kij->bij", w_hat, JtJ) / self.scale,
                torch.einsum("bkl,kij->bijl", dw_hat, JtJ) / self.scale)  # fmt: skip
