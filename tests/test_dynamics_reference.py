"""The rollout integrator against an independent reference: torchdiffeq's adaptive dopri5.

The velocity-Verlet scheme of :func:`lagsplat.dynamics.integrators.rollout` (paper Eq. 8) is
second order for a conservative Lagrangian and first order in the dissipative terms; both are
checked by halving the step and reading the error against a tight dopri5 solution of the same
equations of motion (``model.acceleration``).
"""

from __future__ import annotations

import math

import pytest
import torch
from torchdiffeq import odeint

from lagsplat.dynamics.integrators import rollout
from lagsplat.models.lagrangian import Lagrangian

T_END = 2.0  # seconds


def _model(dissipative: bool, seed: int = 0) -> Lagrangian:
    torch.manual_seed(seed)
    m = Lagrangian(2, mass="constant", hidden=(16, 16)).double()
    with torch.no_grad():
        m.init_energy_scales(2 * math.pi * 1.0, 0.05)
    if not dissipative:  # the conservative part alone: Rayleigh matrix C(q) = 0
        m.dissipation_matrix = lambda q: torch.zeros(q.shape[0], m.d, m.d, dtype=q.dtype)
    return m.eval()


def _reference(model: Lagrangian, q0: torch.Tensor, v0: torch.Tensor, n: int, h: float) -> torch.Tensor:
    d = q0.shape[-1]

    def f(t, y):
        with torch.enable_grad():
            q, v = y[..., :d], y[..., d:]
            a = model.acceleration(q, v)
        return torch.cat([v, a.detach()], -1)

    t = torch.arange(n, dtype=torch.float64) * h
    y = odeint(f, torch.cat([q0, v0], -1), t, method="dopri5", rtol=1e-10, atol=1e-12)
    return y[..., :d].transpose(0, 1)  # [B, n, d]


def _error(model: Lagrangian, h: float) -> float:
    q0 = model.q_rest.detach()[None].double() + torch.tensor([[0.6, -0.4]], dtype=torch.float64)
    v0 = torch.tensor([[0.3, 0.5]], dtype=torch.float64)
    n = round(T_END / h) + 1
    q, _ = rollout(model, q0, v0, h, n, fast=False)
    ref = _reference(model, q0, v0, n, h)
    return float((q[0, -1] - ref[0, -1]).norm() / ref[0].norm(dim=-1).max())


@pytest.mark.parametrize("dissipative, order", [(False, 2.0), (True, 1.0)])
def test_verlet_converges_to_the_dopri5_reference_at_its_order(dissipative: bool, order: float) -> None:
    model = _model(dissipative)
    errs = [_error(model, h) for h in (1 / 40, 1 / 80, 1 / 160)]
    rates = [math.log2(errs[i] / errs[i + 1]) for i in range(2)]
    assert errs[-1] < 1e-2, errs
    assert all(r > order - 0.3 for r in rates), (errs, rates)
