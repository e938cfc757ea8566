"""The latent dissipative Lagrangian (paper §3.3, Eq. 7; App. A.2).

``L = T - V`` with ``T = 1/2 qdot^T M qdot`` and Rayleigh dissipation
``D = 1/2 qdot^T C(q) qdot``; the Euler-Lagrange equation (paper Eq. 7) with a
constant inertia reads ``M qddot = -dV/dq - C(q) qdot + f_ext``.

Energy gauge. The dynamics is identified only up to ``(L, D) -> a (L, D)``
(paper §3.4). Inertia, stiffness and the learned part of the dissipation
carry explicit log-scales ``s_M`` and ``s_V``:

    M = exp(s_M) M_hat,   V = exp(s_V) V_hat,   C = exp(s_M) L_C L_C^T + c0 I,

which :func:`init_energy_scales` sets from the data before training so that
the untrained model already oscillates at the frequency seen in the training
video and the floor ``c0`` (paper App. C: 1) damps it by a small, known ratio
``zeta_floor``. Time is in seconds throughout.

Guarantees (App. A.2): ``M`` SPD, ``V`` strongly convex (unique minimum),
``C >= c0 I``; so ``E = T + V`` decreases at least as ``c0 |qdot|^2`` and every
free trajectory settles at the minimum of ``V``.
"""

from __future__ import annotations

import math
from typing import Literal

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from lagsplat.models.icnn import ConvexPotential

__all__ = ["CholeskyField", "Lagrangian"]


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


class Lagrangian(nn.Module):
    """Latent dissipative Lagrangian (paper §3.3).

    Args:
        d: latent dimension.
        mass: ``"scalar"`` (``M = m I``, the paper's d = 1 model),
            ``"constant"`` (a learned constant SPD matrix, ablation) or
            ``"learned"`` (``M(q) = L(q) L(q)^T + eps I`` from an MLP Cholesky
            factor, SPD floor ``eps = 0.1``; its Coriolis terms come from
            ``d(M qdot)/dq`` by autograd, paper §3.3 "Inertia").
        c0: isotropic dissipation floor (paper App. C: 1).
        dissipation_init: initial learned dissipation ``L_C L_C^T`` (0.2 I).
        hidden: MLP / ICNN widths.
        eps_V: quadratic floor of the potential.
        learn_rest: train the rest state ``q*``.

    The single physics entry point is :meth:`acceleration`.
    """

    def __init__(
        self,
        d: int,
        mass: Literal["scalar", "constant"] = "scalar",
        c0: float = 1.0,
        dissipation_init: float = 0.2,
        hidden: tuple[int, ...] = (64, 64),
        eps_V: float = 0.01,
        learn_rest: bool = True,
    ) -> None:
        super().__init__()
        if mass not in ("scalar", "constant", "learned"):
            raise ValueError(f"mass must be 'scalar', 'constant' or 'learned', got {mass!r}")
        self.d, self.mass_kind, self.c0 = int(d), mass, float(c0)
        self.s_M = nn.Parameter(torch.zeros(()))
        self.s_V = nn.Parameter(torch.zeros(()))
        n_tri = d * (d + 1) // 2
        self.M_raw = nn.Parameter(torch.zeros(n_tri)) if mass == "constant" else None
        self.mass_field = CholeskyField(d, hidden, 1.0) if mass == "learned" else None
        self.dissipation = CholeskyField(d, hidden, dissipation_init)
        self.potential_hat = ConvexPotential(d, hidden, eps_V, learn_rest=learn_rest)
        ii, jj = torch.tril_indices(d, d)
        self.register_buffer("ii", ii, persistent=False)
        self.register_buffer("jj", jj, persistent=False)

    # ------------------------------------------------------------ components
    def mass_matrix(self, q: Tensor) -> Tensor:
        """Inertia ``M(q) [B,d,d]``, SPD."""
        B = q.shape[0]
        m = torch.exp(self.s_M)
        eye = torch.eye(self.d, dtype=q.dtype, device=q.device)
        if self.mass_field is not None:  # L L^T = I at initialisation, so M = m I there
            return m * (self.mass_field(q) + 0.1 * eye) / 1.1
        if self.M_raw is None:
            M = m * torch.eye(self.d, dtype=q.dtype, device=q.device)
        else:
            diag = self.ii == self.jj
            raw = torch.where(diag, F.softplus(self.M_raw + 0.5413), self.M_raw)  # softplus(0.5413) = 1
            L = raw.new_zeros(self.d, self.d)
            L[self.ii, self.jj] = raw
            M = m * (L @ L.T + 0.1 * torch.eye(self.d, dtype=q.dtype, device=q.device)) / 1.1
        return M.expand(B, self.d, self.d)

    def dissipation_matrix(self, q: Tensor) -> Tensor:
        """Rayleigh matrix ``C(q) = e^{s_M} L_C L_C^T + c0 I``, ``[B,d,d]``."""
        eye = torch.eye(self.d, dtype=q.dtype, device=q.device)
        return torch.exp(self.s_M) * self.dissipation(q) + self.c0 * eye

    def potential(self, q: Tensor) -> Tensor:
        """Potential energy ``V(q) [B]``."""
        return torch.exp(self.s_V) * self.potential_hat(q)

    def potential_grad(self, q: Tensor, create_graph: bool | None = None) -> Tensor:
        """``dV/dq [B,d]`` by autograd (graph kept while training)."""
        cg = self.training if create_graph is None else create_graph
        with torch.enable_grad():
            q_ = q if q.requires_grad else q.detach().requires_grad_(True)
            (g,) = torch.autograd.grad(self.potential(q_).sum(), q_, create_graph=cg)
        return g

    @property
    def q_rest(self) -> Tensor:
        """The unique minimum of ``V`` (rest state), ``[d]``."""
        return self.potential_hat.q_rest

    def energies(self, q: Tensor, qdot: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """``(T, V, D)``, each ``[B]``: kinetic, potential and Rayleigh dissipation."""
        M = self.mass_matrix(q)
        C = self.dissipation_matrix(q)
        T = 0.5 * torch.einsum("bi,bij,bj->b", qdot, M, qdot)
        D = 0.5 * torch.einsum("bi,bij,bj->b", qdot, C, qdot)
        return T, self.potential(q), D

    # --------------------------------------------------------------- physics
    def acceleration(self, q: Tensor, qdot: Tensor, f_ext: Tensor | None = None) -> Tensor:
        """Solve the Euler-Lagrange equation (paper Eq. 7) for ``qddot``.

        Args:
            q, qdot: ``[B,d]`` state (whitened latent units, per second).
            f_ext: ``[B,d]`` generalized external force, or ``None``.

        Returns:
            ``qddot [B,d]``. Differentiable (second order) in training mode.
        """
        force = -self.potential_grad(q) - torch.einsum("bij,bj->bi", self.dissipation_matrix(q), qdot)
        if f_ext is not None:
            force = force + f_ext
        if self.mass_field is not None:
            # M qddot = dT/dq - (d(M qdot)/dq) qdot + ...   (paper Eq. 7 with M(q))
            cg = self.training
            with torch.enable_grad():
                q_ = q if q.requires_grad else q.detach().requires_grad_(True)
                M = self.mass_matrix(q_)
                p = torch.einsum("bij,bj->bi", M, qdot)
                (dT,) = torch.autograd.grad(0.5 * (p * qdot).sum(), q_, create_graph=cg, retain_graph=True)
                rows = [torch.autograd.grad(p[:, i].sum(), q_, create_graph=cg, retain_graph=True)[0] for i in range(self.d)]
            coriolis = torch.einsum("bij,bj->bi", torch.stack(rows, 1), qdot)
            force = force + dT - coriolis
            if not cg:
                M, force = M.detach(), force.detach()
            return torch.linalg.solve(M, force.unsqueeze(-1)).squeeze(-1)
        M = self.mass_matrix(q)
        if self.M_raw is None:
            return force / M[:, 0, 0:1]
        return torch.linalg.solve(M, force.unsqueeze(-1)).squeeze(-1)

    @torch.no_grad()
    def init_energy_scales(self, omega: float, zeta_floor: float = 0.01) -> None:
        """Fix the energy gauge from data (see module docstring).

        Sets ``s_M`` so that the floor alone gives damping ratio ``zeta_floor``
        at angular frequency ``omega`` (rad/s), then ``s_V`` so that the
        curvature of ``V`` at rest over the inertia equals ``omega^2``.

        Raises:
            ValueError: if ``omega`` or ``zeta_floor`` is not positive.
        """
        if not (omega > 0 and zeta_floor > 0):
            raise ValueError(f"need omega > 0 and zeta_floor > 0, got {omega}, {zeta_floor}")
        m = self.c0 / (2.0 * zeta_floor * omega)
        self.s_M.fill_(math.log(m))
        self.s_V.zero_()
        with torch.enable_grad():
            q = self.q_rest.detach().clone()[None].requires_grad_(True)
            (g,) = torch.autograd.grad(self.potential(q).sum(), q, create_graph=True)
            H = torch.stack([torch.autograd.grad(g[0, i], q, retain_graph=True)[0][0] for i in range(self.d)])
        k = float(torch.linalg.eigvalsh(0.5 * (H + H.T)).mean())
        self.s_V.fill_(math.log(m * omega**2 / max(k, 1e-12)))
