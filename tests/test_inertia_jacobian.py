"""Forward-mode derivatives of the position-dependent inertias (paper Eq. 7): the learned Cholesky field and the
decoder-induced inertia against autograd's Jacobian, and the Euler-Lagrange acceleration built on them against the
autograd construction ``dT/dq - (d(M qdot)/dq) qdot``, values and parameter gradients."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from lagsplat.models.decoder import ConditionedGaussians
from lagsplat.models.inertia import CholeskyField, DecoderInertia
from lagsplat.models.lagrangian import Lagrangian

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _randomise(module: torch.nn.Module, seed: int, scale: float = 0.5) -> None:
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in module.parameters():
            p.add_(scale * torch.randn(p.shape, generator=g, dtype=p.dtype))


def _autograd_jacobian(field: torch.nn.Module, q: torch.Tensor) -> torch.Tensor:
    """``[B,d,d,d]``, ``[b,i,j,k] = d field(q)_ij / dq_k``, by autograd, sample by sample."""
    return torch.stack([torch.autograd.functional.jacobian(lambda x: field(x[None])[0], qi) for qi in q])


@pytest.mark.parametrize("d", [1, 2, 3])
def test_cholesky_field_jacobian_matches_autograd(d: int) -> None:
    field = CholeskyField(d, (16, 12), 0.3).double()
    _randomise(field.net[-1], d)  # the last layer starts at zero weight: give the field a slope
    q = torch.randn(7, d, dtype=torch.float64, generator=torch.Generator().manual_seed(1)) * 1.5
    S, dS = field.value_and_jacobian(q)
    np.testing.assert_allclose(S.detach().numpy(), field(q).detach().numpy(), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(dS.detach().numpy(), _autograd_jacobian(field, q).numpy(), rtol=1e-9, atol=1e-10)
    assert float(dS.detach().abs().max()) > 1e-3  # the randomised field does change with q


def test_decoder_inertia_jacobian_matches_autograd_inside_and_beyond_the_gate_clamp() -> None:
    torch.manual_seed(0)
    d, K = 2, 30
    dec = ConditionedGaussians(K, d)
    dec.init_from_frame(torch.rand(3, 16, 16), torch.randn(50, d))
    with torch.no_grad():
        dec.L_raw[:, d + 1 : d + 1 + d] = torch.randn(K, d) * 0.3
    W_inv = torch.tensor([[1.5, 0.2], [-0.3, 0.8]])
    inert = DecoderInertia.from_decoder(dec, W_inv, torch.tensor([0.1, -0.2]), 24, 32).double()
    q = torch.cat([torch.randn(5, d, dtype=torch.float64), torch.tensor([[6.0, -5.0]], dtype=torch.float64)])
    M, dM = inert.value_and_jacobian(q)
    np.testing.assert_allclose(M.numpy(), inert(q).numpy(), rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(dM.numpy(), _autograd_jacobian(inert, q).numpy(), rtol=1e-7, atol=1e-9)
    assert float(dM[:5].abs().max()) > 1e-3


def _reference_acceleration(m: Lagrangian, q: torch.Tensor, qdot: torch.Tensor) -> torch.Tensor:
    """Eq. 7 with ``M(q)`` by double autograd: ``M qddot = dT/dq - (d(M qdot)/dq) qdot - dV/dq - C qdot``."""
    q_ = q.requires_grad_(True) if not q.requires_grad else q
    M = m.mass_matrix(q_)
    p = torch.einsum("bij,bj->bi", M, qdot)
    (dT,) = torch.autograd.grad(0.5 * (p * qdot).sum(), q_, create_graph=True)
    rows = torch.stack([torch.autograd.grad(p[:, i].sum(), q_, create_graph=True)[0] for i in range(m.d)], 1)
    force = -m.potential_grad(q_, create_graph=True) - torch.einsum("bij,bj->bi", m.dissipation_matrix(q_), qdot)
    force = force + dT - torch.einsum("bij,bj->bi", rows, qdot)
    return torch.linalg.solve(M, force.unsqueeze(-1)).squeeze(-1)


@pytest.mark.parametrize("d", [1, 2])
def test_learned_inertia_acceleration_and_its_gradients_match_the_autograd_construction(d: int) -> None:
    torch.manual_seed(d)
    m = Lagrangian(d, "learned", hidden=(16, 16)).double()
    m.init_energy_scales(2 * math.pi * 0.7, 0.02)
    _randomise(m.mass_field, 10 + d)
    m.train()
    gen = torch.Generator().manual_seed(3)
    q = torch.randn(6, d, dtype=torch.float64, generator=gen)
    qdot = 2.0 * torch.randn(6, d, dtype=torch.float64, generator=gen)

    a = m.acceleration(q.clone().requires_grad_(True), qdot)
    a_ref = _reference_acceleration(m, q.clone(), qdot)
    np.testing.assert_allclose(a.detach().numpy(), a_ref.detach().numpy(), rtol=1e-9, atol=1e-10)
    with torch.no_grad():  # a_ref less the velocity-free and dissipative parts: the Coriolis terms alone
        damping = torch.linalg.solve(m.mass_matrix(q), torch.einsum("bij,bj->bi", m.dissipation_matrix(q), qdot).unsqueeze(-1)).squeeze(-1)
        coriolis = a_ref - m.acceleration(q, torch.zeros_like(qdot)) + damping
    assert float(coriolis.abs().max()) > 1e-3  # the velocity terms of M(q) are exercised, not zero

    params = [p for p in m.parameters() if p.requires_grad]
    g_new = torch.autograd.grad((m.acceleration(q, qdot) ** 2).sum(), params, allow_unused=True)
    g_ref = torch.autograd.grad((_reference_acceleration(m, q.clone(), qdot) ** 2).sum(), params, allow_unused=True)
    for gn, gr in zip(g_new, g_ref):
        if gr is None:
            assert gn is None or float(gn.abs().max()) == 0.0
            continue
        np.testing.assert_allclose(gn.numpy(), gr.numpy(), rtol=1e-8, atol=1e-10)


def test_the_inertia_derivative_of_a_constant_mass_is_refused() -> None:
    with pytest.raises(ValueError, match="constant inertia"):
        Lagrangian(1, "scalar").mass_matrix_and_derivative(torch.zeros(2, 1))


@pytest.mark.parametrize("d,potential", [(1, "convex"), (3, "convex"), (2, "invex"), (3, "invex")])
def test_the_potentials_closed_form_gradient_matches_autograd(d: int, potential: str) -> None:
    torch.manual_seed(d)
    m = Lagrangian(d, "scalar", hidden=(16, 12, 8), potential=potential).double()
    _randomise(m.potential_hat, 20 + d, scale=0.3)
    q = torch.randn(9, d, dtype=torch.float64, generator=torch.Generator().manual_seed(4)).requires_grad_(True)
    (ref,) = torch.autograd.grad(m.potential(q).sum(), q, create_graph=True)
    g = m.potential_grad(q, create_graph=True)
    np.testing.assert_allclose(g.detach().numpy(), ref.detach().numpy(), rtol=1e-10, atol=1e-12)
    params = [m.s_V, *m.potential_hat.parameters()]
    for gn, gr in zip(torch.autograd.grad((g**3).sum(), params), torch.autograd.grad((ref**3).sum(), params)):
        np.testing.assert_allclose(gn.numpy(), gr.numpy(), rtol=1e-8, atol=1e-11)
    m.eval()
    assert m.potential_grad(q).grad_fn is None  # detached outside training, as autograd's create_graph=False


def test_the_actuation_maps_closed_form_force_and_nonlinearity_match_autograd() -> None:
    from lagsplat.models.icnn import ConcaveMap

    torch.manual_seed(0)
    act = ConcaveMap(3, 4, hidden=(8, 6)).double()
    _randomise(act, 30, scale=0.4)
    gen = torch.Generator().manual_seed(5)
    q = torch.randn(7, 3, dtype=torch.float64, generator=gen).requires_grad_(True)
    P = torch.rand(7, 4, dtype=torch.float64, generator=gen)
    (ref,) = torch.autograd.grad((act(q) * P).sum(), q, create_graph=True)
    f = act.force(q, P, create_graph=True)
    np.testing.assert_allclose(f.detach().numpy(), ref.detach().numpy(), rtol=1e-10, atol=1e-12)
    params = list(act.parameters())
    for gn, gr in zip(torch.autograd.grad((f**2).sum(), params), torch.autograd.grad((ref**2).sum(), params)):
        np.testing.assert_allclose(gn.numpy(), gr.numpy(), rtol=1e-8, atol=1e-11)
    assert act.force(q, P).grad_fn is None
    x = q.detach().requires_grad_(True)
    (g,) = torch.autograd.grad(sum(h(x).sum() for h in act.heads), x)
    assert float(act.nonlinearity(q)) == pytest.approx(float((g**2).sum(-1).mean()), rel=1e-12)
