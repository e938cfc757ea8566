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

import copy
import math
from typing import Literal

import numpy as np

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from lagsplat.models.inertia import CholeskyField, DecoderInertia
from lagsplat.models.icnn import ConcaveMap, ConvexPotential

__all__ = ["Lagrangian", "MASS_KINDS"]

#: Inertia forms selectable by ``stage2.mass`` (paper §3.3 "Inertia").
MASS_KINDS = ("scalar", "constant", "learned", "decoder")


class Lagrangian(nn.Module):
    """Latent dissipative Lagrangian (paper §3.3).

    Args:
        d: latent dimension.
        mass: ``"scalar"`` (``M = m I``, the paper's d = 1 model),
            ``"constant"`` (a learned constant SPD matrix, ablation) or
            ``"learned"`` (``M(q) = L(q) L(q)^T + eps I`` from an MLP Cholesky
            factor, SPD floor ``eps = 0.1``; its Coriolis terms come from
            ``d(M qdot)/dq`` in forward mode, paper §3.3 "Inertia") or
            ``"decoder"`` (``M(q) = m (M_hat(q) + 0.1 I) / 1.1`` with ``M_hat`` the
            :class:`DecoderInertia` passed as ``inertia``; ``m = exp(s_M)`` is
            frozen after :meth:`init_energy_scales`, so the form has no learned
            parameter, paper Eq. 7).
        c0: isotropic dissipation floor (paper App. C: 1).
        dissipation_init: initial learned dissipation ``L_C L_C^T`` (0.2 I).
        hidden: MLP / ICNN widths.
        eps_V: quadratic floor of the potential.
        learn_rest: train the rest state ``q*``.
        potential: ``"convex"`` (ICNN) or ``"invex"`` (ICNN o i-ResNet), paper §3.3.
        n_u: number of measured actuation channels (``0``: none). With
            ``n_u > 0`` a :class:`~lagsplat.models.icnn.ConcaveMap` ``nu(q)``
            turns pressures ``u >= 0`` into ``f_P = b(q)^T u`` (paper Eq. 6).
        inertia: the :class:`DecoderInertia` (``mass="decoder"`` only).

    The single physics entry point is :meth:`acceleration`.

    Raises:
        ValueError: on an unknown ``mass`` / ``potential`` or a missing ``inertia``.
    """

    def __init__(
        self,
        d: int,
        mass: Literal["scalar", "constant", "learned", "decoder"] = "scalar",
        c0: float = 1.0,
        dissipation_init: float = 0.2,
        hidden: tuple[int, ...] = (64, 64),
        eps_V: float = 0.01,
        learn_rest: bool = True,
        potential: Literal["convex", "invex"] = "convex",
        n_u: int = 0,
        inertia: DecoderInertia | None = None,
    ) -> None:
        super().__init__()
        if mass not in MASS_KINDS:
            raise ValueError(f"mass must be one of {MASS_KINDS}, got {mass!r}")
        if potential not in ("convex", "invex"):
            raise ValueError(f"potential must be 'convex' or 'invex', got {potential!r}")
        if mass == "decoder" and inertia is None:
            raise ValueError("mass='decoder' needs the DecoderInertia built from the trained decoder")
        self.d, self.mass_kind, self.c0, self.potential_kind = int(d), mass, float(c0), potential
        self.s_M = nn.Parameter(torch.zeros(()), requires_grad=mass != "decoder")
        self.s_V = nn.Parameter(torch.zeros(()))
        n_tri = d * (d + 1) // 2
        self.M_raw = nn.Parameter(torch.zeros(n_tri)) if mass == "constant" else None
        if mass == "learned":
            self.mass_field: nn.Module | None = CholeskyField(d, hidden, 1.0)
        elif mass == "decoder":
            self.mass_field = inertia
        else:
            self.mass_field = None
        self.dissipation = CholeskyField(d, hidden, dissipation_init)
        self.potential_hat = ConvexPotential(d, hidden, eps_V, learn_rest=learn_rest, invex=potential == "invex")
        self.n_u = int(n_u)
        self.actuation = ConcaveMap(d, n_u) if n_u > 0 else None
        ii, jj = torch.tril_indices(d, d)
        self.register_buffer("ii", ii, persistent=False)
        self.register_buffer("jj", jj, persistent=False)

    # ------------------------------------------------------------ components
    def mass_matrix(self, q: Tensor) -> Tensor:
        """Inertia ``M(q) [B,d,d]``, SPD."""
        B = q.shape[0]
        m = torch.exp(self.s_M)
        if self.mass_field is not None:  # L L^T = I (learned) / trace-d M_hat (decoder) at start
            return self._floored(self.mass_field(q))
        if self.M_raw is None:
            M = m * torch.eye(self.d, dtype=q.dtype, device=q.device)
        else:
            diag = self.ii == self.jj
            raw = torch.where(diag, F.softplus(self.M_raw + 0.5413), self.M_raw)  # softplus(0.5413) = 1
            L = raw.new_zeros(self.d, self.d)
            L[self.ii, self.jj] = raw
            M = m * (L @ L.T + 0.1 * torch.eye(self.d, dtype=q.dtype, device=q.device)) / 1.1
        return M.expand(B, self.d, self.d)

    def mass_matrix_and_derivative(self, q: Tensor) -> tuple[Tensor, Tensor]:
        """``(M, dM)`` of a position-dependent inertia: ``M(q) [B,d,d]`` (:meth:`mass_matrix`) and
        ``dM [B,d,d,d]``, ``dM[b,i,j,k] = dM_ij / dq_k`` (the Coriolis terms of paper Eq. 7), by the field's
        forward-mode ``value_and_jacobian``: first-order differentiable, no second autograd pass.

        Raises:
            ValueError: if the inertia is constant (``mass`` ``"scalar"`` or ``"constant"``).
        """
        if self.mass_field is None:
            raise ValueError("a constant inertia has no derivative field (mass is 'scalar' or 'constant')")
        S, dS = self.mass_field.value_and_jacobian(q)
        return self._floored(S), torch.exp(self.s_M) * dS / 1.1

    def _floored(self, S: Tensor) -> Tensor:
        """``M = m (S + 0.1 I) / 1.1`` of a field ``S [B,d,d]`` (the SPD floor of a position-dependent inertia)."""
        eye = torch.eye(self.d, dtype=S.dtype, device=S.device)
        return torch.exp(self.s_M) * (S + 0.1 * eye) / 1.1

    def dissipation_matrix(self, q: Tensor) -> Tensor:
        """Rayleigh matrix ``C(q) = e^{s_M} L_C L_C^T + c0 I``, ``[B,d,d]``."""
        eye = torch.eye(self.d, dtype=q.dtype, device=q.device)
        return torch.exp(self.s_M) * self.dissipation(q) + self.c0 * eye

    def potential(self, q: Tensor) -> Tensor:
        """Potential energy ``V(q) [B]``."""
        return torch.exp(self.s_V) * self.potential_hat(q)

    def potential_grad(self, q: Tensor, create_graph: bool | None = None) -> Tensor:
        """``dV/dq [B,d]`` in closed form (:meth:`ConvexPotential.gradient`, convex or invex): differentiable while
        training (or with ``create_graph``), detached otherwise."""
        cg = self.training if create_graph is None else create_graph
        g = torch.exp(self.s_V) * self.potential_hat.gradient(q)
        return g if cg else g.detach()

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
    def actuation_force(self, q: Tensor, u: Tensor) -> Tensor:
        """``f_P = b(q)^T u [B,d]`` for actuation ``u [B,n_u]`` (paper Eq. 6).

        Raises:
            ValueError: if the model has no actuation channels or ``u`` has the wrong width.
        """
        if self.actuation is None:
            raise ValueError("this model has no actuation channels (n_u = 0) but an actuation u was given")
        if u.shape[-1] != self.n_u:
            raise ValueError(f"actuation u has {u.shape[-1]} channels, the model {self.n_u}")
        return torch.exp(self.s_V) * self.actuation.force(q, u, create_graph=self.training)

    def generalized_force(self, q: Tensor, f_ext: Tensor | None = None, u: Tensor | None = None) -> Tensor | None:
        """Total external generalized force ``f_ext + b(q)^T u`` (``None`` when both are absent)."""
        if u is not None and self.actuation is not None:
            fp = self.actuation_force(q, u)
            return fp if f_ext is None else f_ext + fp
        if u is not None:
            self.actuation_force(q, u)  # raises
        return f_ext

    def acceleration(self, q: Tensor, qdot: Tensor, f_ext: Tensor | None = None, u: Tensor | None = None) -> Tensor:
        """Solve the Euler-Lagrange equation (paper Eq. 7) for ``qddot``.

        ``M(q) qddot = dT/dq - (d(M qdot)/dq) qdot - dV/dq - C(q) qdot + f_ext + b(q)^T u``.

        Args:
            q, qdot: ``[B,d]`` state (whitened latent units, per second).
            f_ext: ``[B,d]`` generalized external force, or ``None``.
            u: ``[B,n_u]`` measured actuation (e.g. pressures), or ``None``.

        Returns:
            ``qddot [B,d]``. Differentiable (second order) in training mode.
        """
        force = -self.potential_grad(q) - torch.einsum("bij,bj->bi", self.dissipation_matrix(q), qdot)
        f_ext = self.generalized_force(q, f_ext, u)
        if f_ext is not None:
            force = force + f_ext
        if self.mass_field is not None:
            # M qddot = dT/dq - (d(M qdot)/dq) qdot + ...   (paper Eq. 7 with M(q)); dM/dq in forward mode
            M, dM = self.mass_matrix_and_derivative(q)
            dT = 0.5 * torch.einsum("bijk,bi,bj->bk", dM, qdot, qdot)
            coriolis = torch.einsum("bijk,bj,bk->bi", dM, qdot, qdot)
            force = force + dT - coriolis
            return torch.linalg.solve(M, force.unsqueeze(-1)).squeeze(-1)
        M = self.mass_matrix(q)
        if self.M_raw is None:
            return force / M[:, 0, 0:1]
        return torch.linalg.solve(M, force.unsqueeze(-1)).squeeze(-1)

    def loaded_potential(self, q: Tensor, f_ext: Tensor | None = None, u: Tensor | None = None) -> Tensor:
        """``V(q) - f^T q - e^{s_V} u^T nu(q)`` ``[B]``: the potential under a constant load.

        With the convex potential and ``u >= 0`` it is strongly convex and its
        unique minimum is the loaded equilibrium. The invex potential has a
        single stationary point only without load: ``V - f^T q`` stays coercive
        but may have several stationary points (tests/test_properties.py
        records a case), so a load can give several equilibria.
        """
        Vf = self.potential(q)
        if f_ext is not None:
            Vf = Vf - (f_ext * q).sum(-1)
        if u is not None:
            if self.actuation is None:
                raise ValueError("this model has no actuation channels (n_u = 0) but an actuation u was given")
            Vf = Vf - torch.exp(self.s_V) * (self.actuation(q) * u).sum(-1)
        return Vf

    def loaded_energy(self, q: Tensor, qdot: Tensor, f_ext: Tensor | None = None, u: Tensor | None = None) -> Tensor:
        """``E_f = T + V - f^T q (- u^T nu)`` ``[B]``; non-increasing under a constant load (App. A.2)."""
        T, _, _ = self.energies(q, qdot)
        return T + self.loaded_potential(q, f_ext, u)

    def loaded_equilibrium(
        self,
        f_ext: Tensor | None = None,
        u: Tensor | None = None,
        q0: Tensor | None = None,
        tol: float = 1e-6,
        max_iter: int = 200,
    ) -> Tensor:
        """Solve ``dV/dq = f_ext + b(q)^T u`` for ``q`` (the loaded equilibrium).

        Damped Newton on the loaded potential (Levenberg-regularised Hessian,
        backtracking on the loaded potential or on the gradient norm), in
        float64 on a copy of the model. For the convex potential the result is
        the unique loaded equilibrium; for the invex one it is a local minimum
        of the loaded potential reached from ``q0`` (possibly one of several).

        Args:
            f_ext: ``[B,d]`` constant generalized force (or ``None``).
            u: ``[B,n_u]`` constant actuation (or ``None``).
            q0: ``[B,d]`` start (default: the rest state).
            tol: stop when ``|grad|_inf <= tol * (1 + |f|_inf + |e^{s_V} b^T u|_inf)``.
            max_iter: Newton iterations.

        Returns:
            ``q_eq [B,d]`` (no gradient).

        Raises:
            RuntimeError: if it has not converged after ``max_iter`` iterations.
        """
        ref = f_ext if f_ext is not None else u
        B = 1 if ref is None else ref.shape[0]
        dtype = self.s_V.dtype
        model = copy.deepcopy(self).double().eval()
        q = (self.q_rest.detach()[None].expand(B, self.d) if q0 is None else q0.detach()).double().clone()
        eye = torch.eye(self.d, dtype=q.dtype)
        fd = None if f_ext is None else f_ext.detach().double()
        ud = None if u is None else u.detach().double()
        scale = 1.0
        if fd is not None:
            scale += float(fd.abs().max())
        if ud is not None:
            scale += float(model.actuation_force(q, ud).detach().abs().max())
        tol = tol * scale

        def value_grad_hess(x: Tensor) -> tuple[Tensor, Tensor, Tensor]:
            with torch.enable_grad():
                x = x.detach().requires_grad_(True)
                v = model.loaded_potential(x, fd, ud)
                (g,) = torch.autograd.grad(v.sum(), x, create_graph=True)
                H = torch.stack([torch.autograd.grad(g[:, i].sum(), x, retain_graph=True)[0] for i in range(self.d)], 1)
            return v.detach(), g.detach(), H.detach()

        lam = torch.full((B, 1, 1), 1e-6, dtype=q.dtype)
        for _ in range(max_iter):
            v, g, H = value_grad_hess(q)
            if float(g.abs().max()) < tol:
                return q.to(dtype)
            Hs = 0.5 * (H + H.transpose(1, 2))
            shift = (-torch.linalg.eigvalsh(Hs)[:, :1]).clamp_min(0.0)[..., None] * 1.01
            step = torch.linalg.solve(Hs + (shift + lam * (1 + Hs.diagonal(dim1=1, dim2=2).abs().amax(-1, keepdim=True)[..., None])) * eye, g.unsqueeze(-1)).squeeze(-1)
            t = torch.ones(B, 1, dtype=q.dtype)
            for _ls in range(30):
                q_new = q - t * step
                v_new, g_new, _ = value_grad_hess(q_new)
                # Armijo on the value, or (near the solution, where the value's rounding
                # error exceeds the decrease sought) a smaller gradient
                ok = (v_new <= v - 1e-4 * t[:, 0] * (g * step).sum(-1)) | (g_new.norm(dim=-1) < 0.9 * g.norm(dim=-1))
                if bool(ok.all()):
                    break
                t = torch.where(ok[:, None], t, 0.5 * t)
            q = q - t * step
        _, g, _ = value_grad_hess(q)
        if float(g.abs().max()) < 10 * tol:
            return q.to(dtype)
        raise RuntimeError(f"loaded equilibrium not found after {max_iter} Newton steps (|grad| = {float(g.abs().max()):.2e})")

    @torch.no_grad()
    def init_energy_scales(self, omega: float, zeta_floor: float = 0.01) -> None:
        """Fix the energy gauge from data (see module docstring).

        Sets ``s_M`` so that the floor alone gives damping ratio ``zeta_floor``
        at angular frequency ``omega`` (rad/s) for a unit inertia, then ``s_V``
        so that the mean eigenvalue of ``M(q*)^-1 d2V/dq2(q*)`` equals
        ``omega^2`` (the untrained model's mean squared natural frequency).

        Raises:
            ValueError: if ``omega`` or ``zeta_floor`` is not positive.
        """
        if not (omega > 0 and zeta_floor > 0):
            raise ValueError(f"need omega > 0 and zeta_floor > 0, got {omega}, {zeta_floor}")
        m = self.c0 / (2.0 * zeta_floor * omega)
        self.s_M.fill_(math.log(m))
        self.s_V.zero_()
        H = self.potential_hessian(self.q_rest.detach()[None])[0]
        M = self.mass_matrix(self.q_rest.detach()[None])[0]
        lam = torch.linalg.eigvals(torch.linalg.solve(M, H)).real.mean()
        self.s_V.fill_(math.log(omega**2 / max(float(lam), 1e-12)))

    def potential_hessian(self, q: Tensor) -> Tensor:
        """``d2V/dq2 [B,d,d]`` by double autograd (no graph kept)."""
        with torch.enable_grad():
            x = q.detach().clone().requires_grad_(True)
            (g,) = torch.autograd.grad(self.potential(x).sum(), x, create_graph=True)
            H = torch.stack([torch.autograd.grad(g[:, i].sum(), x, retain_graph=True)[0] for i in range(self.d)], 1)
        return 0.5 * (H + H.transpose(1, 2)).detach()

    @torch.no_grad()
    def modal_analysis(self, q: Tensor | None = None) -> dict[str, np.ndarray]:
        """Linearised modes at ``q`` (default: the rest state).

        Solves the quadratic eigenproblem ``(lambda^2 M + lambda C + K) phi = 0``
        with ``M, C, K`` the inertia, dissipation and potential Hessian at
        ``q``, through its first-order companion form.

        Returns:
            ``{"f_hz": [d], "zeta": [d], "f_damped_hz": [d]}``, sorted by
            frequency: undamped-equivalent natural frequency ``|lambda| / 2 pi``,
            damping ratio ``-Re(lambda) / |lambda|`` and damped frequency
            ``Im(lambda) / 2 pi`` of each under-damped pair (over-damped real
            roots are reported with ``f_damped_hz = 0``).
        """
        q = self.q_rest.detach()[None] if q is None else q.detach().reshape(1, self.d)
        M = self.mass_matrix(q)[0].double()
        C = self.dissipation_matrix(q)[0].double()
        K = self.potential_hessian(q)[0].double()
        d = self.d
        Minv = torch.linalg.inv(M)
        A = torch.zeros(2 * d, 2 * d, dtype=torch.float64)
        A[:d, d:] = torch.eye(d, dtype=torch.float64)
        A[d:, :d] = -Minv @ K
        A[d:, d:] = -Minv @ C
        lam = torch.linalg.eigvals(A).numpy()
        # one (|lambda|, zeta, omega_d) per mode: the upper root of each complex pair, or a pair
        # of real (over-damped) roots r1 r2 = wn^2, -(r1 + r2) = 2 zeta wn
        modes = [(abs(r), -r.real / abs(r), r.imag) for r in lam[lam.imag > 1e-9]]
        real = np.sort(lam[np.abs(lam.imag) <= 1e-9].real)
        for r1, r2 in zip(real[0::2], real[1::2]):
            wn = math.sqrt(max(r1 * r2, 0.0))
            modes.append((wn, -0.5 * (r1 + r2) / max(wn, 1e-300), 0.0))
        arr = np.array(sorted(modes)[:d], dtype=np.float64).reshape(-1, 3)
        return {"f_hz": arr[:, 0] / (2 * math.pi), "zeta": arr[:, 1], "f_damped_hz": arr[:, 2] / (2 * math.pi)}
