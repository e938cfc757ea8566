"""Tests of the latent dynamics: Verlet integration (lagsplat.dynamics.integrators),
the dissipative Lagrangian (lagsplat.models.lagrangian) and its convex potential
(lagsplat.models.icnn)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from lagsplat.dynamics.integrators import rollout, verlet_step
from lagsplat.timeseries import spectral_peak_frequency
from lagsplat.models.icnn import ICNN, ConvexPotential
from lagsplat.models.lagrangian import Lagrangian

F64 = torch.float64


# ----------------------------------------------------------------------------- oscillator
class Oscillator:
    """``m x'' = -k x - c x' + f``, vectorised over ``[B,d]``."""

    def __init__(self, m: float, k: float, c: float) -> None:
        self.m, self.k, self.c = m, k, c

    def acceleration(self, q, qdot, f_ext=None):
        force = -self.k * q - self.c * qdot
        if f_ext is not None:
            force = force + f_ext
        return force / self.m

    def exact(self, t: torch.Tensor, x0: float, v0: float) -> torch.Tensor:
        """Underdamped closed form ``x(t) = e^{-zeta w t} (x0 cos wd t + (v0 + zeta w x0)/wd sin wd t)``."""
        w = math.sqrt(self.k / self.m)
        zeta = self.c / (2.0 * math.sqrt(self.k * self.m))
        wd = w * math.sqrt(1.0 - zeta**2)
        return torch.exp(-zeta * w * t) * (x0 * torch.cos(wd * t) + (v0 + zeta * w * x0) / wd * torch.sin(wd * t))

    def energy(self, q, qdot):
        return 0.5 * self.m * (qdot**2).sum(-1) + 0.5 * self.k * (q**2).sum(-1)


def _max_error(osc: Oscillator, h: float, T: float = 10.0, x0: float = 1.0, v0: float = 0.5) -> float:
    n = int(round(T / h)) + 1
    q, _ = rollout(osc, torch.tensor([[x0]], dtype=F64), torch.tensor([[v0]], dtype=F64), h, n)
    t = torch.arange(n, dtype=F64) * h
    return float((q[0, :, 0] - osc.exact(t, x0, v0)).abs().max())


def test_verlet_is_second_order_without_damping() -> None:
    osc = Oscillator(m=1.5, k=6.0, c=0.0)
    errs = [_max_error(osc, h) for h in (0.04, 0.02, 0.01)]
    for coarse, fine in zip(errs, errs[1:]):
        assert 3.0 < coarse / fine < 5.0, errs
    assert errs[-1] < 1e-3


def test_verlet_converges_to_the_damped_solution() -> None:
    # With damping the step is the reference "semi-implicit" Verlet (the second
    # force uses the half-step velocity, the reference code): its local velocity error is
    # O(h^2 c a), so the global error is first order (halving h halves it), not
    # second order as for the conservative scheme above.
    osc = Oscillator(m=1.0, k=4.0, c=0.4)
    errs = [_max_error(osc, h) for h in (0.02, 0.01, 0.005)]
    ratios = [coarse / fine for coarse, fine in zip(errs, errs[1:])]
    for r in ratios:
        assert 1.8 < r < 5.0, errs
    assert errs[-1] < 2e-3


def test_verlet_step_matches_its_stated_formula() -> None:
    osc = Oscillator(m=2.0, k=3.0, c=0.7)
    q, v, h = torch.tensor([[0.3, -1.0]], dtype=F64), torch.tensor([[1.1, 0.2]], dtype=F64), 0.1
    f0, f1 = torch.tensor([[0.5, 0.0]], dtype=F64), torch.tensor([[-0.2, 1.0]], dtype=F64)
    a1 = osc.acceleration(q, v, f0)
    vh = v + 0.5 * h * a1
    q1 = q + h * vh
    v1 = vh + 0.5 * h * osc.acceleration(q1, vh, f1)
    got_q, got_v = verlet_step(osc, q, v, h, f_ext=lambda t: f0 if t == 2.0 else f1, t=2.0)
    torch.testing.assert_close(got_q, q1, rtol=0, atol=1e-15)
    torch.testing.assert_close(got_v, v1, rtol=0, atol=1e-15)


def test_undamped_energy_is_bounded_without_drift() -> None:
    osc = Oscillator(m=1.0, k=4.0, c=0.0)
    h, n = 0.02, 10_001  # 10^4 steps, ~64 periods
    q0 = torch.tensor([[1.0], [0.0], [-0.3]], dtype=F64)
    v0 = torch.tensor([[0.0], [2.0], [1.5]], dtype=F64)
    q, v = rollout(osc, q0, v0, h, n)
    E = osc.energy(q, v)  # [B, n]
    rel = (E - E[:, :1]) / E[:, :1]
    assert rel.abs().max() < 1e-3
    # no secular growth: the error envelope of the last tenth is that of the first tenth
    first, last = rel[:, : n // 10].abs().amax(1), rel[:, -n // 10 :].abs().amax(1)
    assert (last < 1.1 * first).all() and (last > 0.9 * first).all()
    # and no linear trend: the fitted change over the whole run is a small part of the oscillation
    t = np.arange(n) * h
    for row in rel.numpy():
        slope = np.polyfit(t, row, 1)[0]
        assert abs(slope * t[-1]) < 0.05 * np.abs(row).max()


def test_constant_force_shifts_equilibrium() -> None:
    osc = Oscillator(m=1.0, k=2.5, c=1.5)
    f = torch.tensor([[1.0, -0.5]], dtype=F64)
    q, v = rollout(osc, torch.zeros(1, 2, dtype=F64), torch.zeros(1, 2, dtype=F64), 0.02, 2001, f_ext=f)
    torch.testing.assert_close(q[0, -1], f[0] / osc.k, rtol=0, atol=1e-8)
    assert v[0, -1].abs().max() < 1e-8
    # a time-dependent force is evaluated at the step times t0 + i h (start and end of each step)
    seen = []

    def force(t):
        seen.append(t)
        return f

    rollout(osc, torch.zeros(1, 2, dtype=F64), torch.zeros(1, 2, dtype=F64), 0.25, 4, f_ext=force, t0=1.0)
    assert seen == pytest.approx([1.0, 1.25, 1.25, 1.5, 1.5, 1.75])


def test_rollout_shapes_and_initial_state() -> None:
    osc = Oscillator(1.0, 1.0, 0.1)
    q0, v0 = torch.randn(4, 3, dtype=F64), torch.randn(4, 3, dtype=F64)
    q, v = rollout(osc, q0, v0, 0.1, 7)
    assert q.shape == v.shape == (4, 7, 3)
    assert torch.equal(q[:, 0], q0) and torch.equal(v[:, 0], v0)


# ----------------------------------------------------------------------------- Lagrangian
def _model(d: int, mass: str, seed: int, perturb: float = 0.0) -> Lagrangian:
    torch.manual_seed(seed)
    model = Lagrangian(d, mass=mass, hidden=(16, 16)).to(F64).eval()
    with torch.no_grad():
        model.potential_hat.q_rest.copy_(torch.randn(d, dtype=F64))
        if perturb:
            for p in model.parameters():
                p.add_(perturb * torch.randn_like(p))
    return model


@pytest.mark.parametrize("d", [1, 2])
@pytest.mark.parametrize("mass", ["scalar", "constant"])
def test_free_rollout_is_bounded_and_settles_at_rest(d: int, mass: str) -> None:
    model = _model(d, mass, seed=10 * d + (mass == "constant"))  # untrained, random q_rest
    gen = torch.Generator().manual_seed(d)
    B = 6
    q0 = model.q_rest.detach() + 2.0 * torch.randn(B, d, generator=gen, dtype=F64)
    v0 = torch.randn(B, d, generator=gen, dtype=F64)
    q, v = rollout(model, q0, v0, 0.075, 401)  # 30 s
    assert torch.isfinite(q).all() and torch.isfinite(v).all()
    dist = (q - model.q_rest.detach()).norm(dim=-1)  # [B, n]
    assert (dist.amax(1) < 10.0 * (dist[:, 0] + v0.norm(dim=-1))).all()  # bounded
    assert (dist[:, -1] < 1e-3 * dist[:, 0]).all()  # settled at the rest state
    assert (v[:, -1].norm(dim=-1) < 1e-3).all()


@pytest.mark.parametrize("d,mass", [(1, "scalar"), (2, "constant")])
def test_energy_does_not_increase_along_free_rollout(d: int, mass: str) -> None:
    model = _model(d, mass, seed=3 + d, perturb=0.2)
    gen = torch.Generator().manual_seed(7)
    q0 = model.q_rest.detach() + torch.randn(4, d, generator=gen, dtype=F64)
    v0 = torch.randn(4, d, generator=gen, dtype=F64)
    q, v = rollout(model, q0, v0, 0.01, 401)
    with torch.no_grad():
        T, V, D = model.energies(q.reshape(-1, d), v.reshape(-1, d))
    E = (T + V).reshape(4, -1)
    assert (V >= 0).all() and (D >= 0).all()
    steps = E[:, 1:] - E[:, :-1]
    # non-increasing up to the O(h^2) integration error
    assert (steps < 1e-6 * E[:, :1]).all(), float((steps / E[:, :1]).max())
    assert (E[:, -1] < 0.5 * E[:, 0]).all()  # and it is really dissipated


@pytest.mark.parametrize("mass", ["scalar", "constant"])
def test_init_energy_scales_sets_the_oscillation_frequency(mass: str) -> None:
    f_hz = 1.3
    omega = 2 * math.pi * f_hz
    model = _model(1, mass, seed=5)
    model.init_energy_scales(omega, zeta_floor=0.01)
    dt = 0.02  # omega dt = 0.16: the Verlet period error is ~1e-3
    q0 = model.q_rest.detach()[None] + 1e-3
    q, _ = rollout(model, q0, torch.zeros(1, 1, dtype=F64), dt, 600)  # 12 s, ~15 cycles
    est = spectral_peak_frequency(q[0, :, 0].numpy(), dt)
    assert abs(est - f_hz) / f_hz < 0.02, est
    # the floor alone gives damping ratio zeta_floor: m = c0 / (2 zeta omega)
    assert math.exp(float(model.s_M)) == pytest.approx(model.c0 / (2 * 0.01 * omega), rel=1e-9)
    with pytest.raises(ValueError):
        model.init_energy_scales(-1.0)


@pytest.mark.parametrize("d,mass", [(1, "scalar"), (2, "scalar"), (2, "constant"), (3, "constant")])
def test_acceleration_solves_euler_lagrange(d: int, mass: str) -> None:
    model = _model(d, mass, seed=8 + d, perturb=0.3)
    gen = torch.Generator().manual_seed(d)
    B = 5
    q = torch.randn(B, d, generator=gen, dtype=F64)
    qdot = torch.randn(B, d, generator=gen, dtype=F64)
    f = torch.randn(B, d, generator=gen, dtype=F64)
    qq = q.clone().requires_grad_(True)
    (gradV,) = torch.autograd.grad(model.potential(qq).sum(), qq)
    # the gradient of V, independently by central differences
    eps = 1e-6
    fd = torch.stack(
        [(model.potential(q + eps * e) - model.potential(q - eps * e)) / (2 * eps) for e in torch.eye(d, dtype=F64)], -1
    ).detach()
    torch.testing.assert_close(gradV, fd, rtol=1e-6, atol=1e-8)
    with torch.no_grad():
        M = model.mass_matrix(q)
        C = model.dissipation_matrix(q)
        assert (torch.linalg.eigvalsh(M) > 0).all()
        assert (torch.linalg.eigvalsh(C) >= model.c0 - 1e-9).all()
        if mass == "constant" and d > 1:
            assert (M - torch.diag_embed(torch.diagonal(M, dim1=-2, dim2=-1))).abs().max() > 1e-3  # a full matrix
        force = -gradV - torch.einsum("bij,bj->bi", C, qdot) + f
        expect = torch.linalg.solve(M, force)
        expect_free = torch.linalg.solve(M, force - f)
    torch.testing.assert_close(model.acceleration(q, qdot, f).detach(), expect, rtol=1e-9, atol=1e-12)
    torch.testing.assert_close(model.acceleration(q, qdot).detach(), expect_free, rtol=1e-9, atol=1e-12)
    # kinetic energy uses the same M
    T, _, _ = model.energies(q, qdot)
    torch.testing.assert_close(T.detach(), 0.5 * torch.einsum("bi,bij,bj->b", qdot, M, qdot), rtol=1e-12, atol=0)


def test_acceleration_is_differentiable_in_training_mode() -> None:
    model = _model(2, "constant", seed=1, perturb=0.1).train()
    q = torch.randn(3, 2, dtype=F64)
    qdot = torch.randn(3, 2, dtype=F64)
    q1, v1 = verlet_step(model, q, qdot, 0.05)
    (q1.sum() + v1.sum()).backward()
    for name, p in model.named_parameters():
        assert p.grad is not None and torch.isfinite(p.grad).all(), name
    assert model.potential_hat.g.inp[0].weight.grad.abs().max() > 0  # through dV/dq (second order)


# ----------------------------------------------------------------------------- ICNN / potential
def _perturbed(module: torch.nn.Module, seed: int) -> torch.nn.Module:
    """Move every parameter away from its initial value (negative raw weights included)."""
    with torch.random.fork_rng(), torch.no_grad():  # leave the global RNG alone
        torch.manual_seed(seed)
        module = module.to(F64)
        for p in module.parameters():
            p.add_(torch.randn_like(p))
    return module


_D = 3
with torch.random.fork_rng():
    torch.manual_seed(0)
    _NET = _perturbed(ICNN(_D, (16, 16)), seed=1)
    _POT = _perturbed(ConvexPotential(_D, (16, 16), eps=0.01, q_rest=torch.tensor([0.5, -1.0, 2.0])), seed=2)

_points = st.lists(st.floats(-4.0, 4.0, allow_nan=False), min_size=_D, max_size=_D)


@settings(max_examples=15, deadline=None)
@given(x=_points)
def test_icnn_hessian_is_psd(x) -> None:
    xt = torch.tensor([x], dtype=F64)
    H = torch.autograd.functional.hessian(lambda z: _NET(z).sum(), xt)[0, :, 0, :]
    torch.testing.assert_close(H, H.T)
    assert torch.linalg.eigvalsh(H).min() > -1e-10


@settings(max_examples=25, deadline=None)
@given(x=_points, y=_points, lam=st.floats(0.0, 1.0))
def test_icnn_is_convex_along_chords(x, y, lam) -> None:
    xt, yt = torch.tensor([x], dtype=F64), torch.tensor([y], dtype=F64)
    with torch.no_grad():
        mid = _NET(lam * xt + (1 - lam) * yt)
        chord = lam * _NET(xt) + (1 - lam) * _NET(yt)
    assert float(mid) <= float(chord) + 1e-9 * (1 + abs(float(chord)))


def test_convex_potential_is_zero_with_zero_gradient_at_rest() -> None:
    qr = _POT.q_rest.detach()[None].clone().requires_grad_(True)
    V = _POT(qr)
    (g,) = torch.autograd.grad(V.sum(), qr)
    assert abs(float(V)) < 1e-12
    assert g.abs().max() < 1e-12
    # learn_rest=False keeps q_rest as a buffer, same anchoring
    fixed = ConvexPotential(2, (8,), q_rest=torch.tensor([1.0, 2.0]), learn_rest=False)
    assert "q_rest" not in dict(fixed.named_parameters())
    assert abs(float(fixed(torch.tensor([[1.0, 2.0]])))) < 1e-6


@settings(max_examples=30, deadline=None)
@given(x=_points)
def test_convex_potential_is_positive_and_strongly_convex_elsewhere(x) -> None:
    q = torch.tensor([x], dtype=F64)
    r2 = float(((q - _POT.q_rest.detach()) ** 2).sum())
    with torch.no_grad():
        V = float(_POT(q))
    # the quadratic floor: V >= eps/2 |q - q*|^2, so V > 0 away from the rest state
    assert V >= 0.5 * _POT.eps * r2 * (1 - 1e-9)
    if r2 > 1e-12:
        assert V > 0


@pytest.mark.parametrize("learn_rest", [True, False])
def test_potential_and_energies_evaluate_under_no_grad(learn_rest: bool) -> None:
    # Evaluation code computes energies without a graph; the anchoring gradient at
    # q_rest must still be taken (regression: it raised under no_grad).
    model = Lagrangian(2, hidden=(8, 8), learn_rest=learn_rest).to(F64)
    q, qdot = torch.randn(3, 2, dtype=F64), torch.randn(3, 2, dtype=F64)
    ref = [e.detach() for e in model.energies(q, qdot)]
    with torch.no_grad():
        got = model.energies(q, qdot)
    for g, r in zip(got, ref):
        assert not g.requires_grad
        torch.testing.assert_close(g, r, rtol=1e-12, atol=0)
    with torch.inference_mode(False), torch.no_grad():
        assert float(model.potential(model.q_rest.detach()[None])) == pytest.approx(0.0, abs=1e-12)


def test_potential_hessian_at_rest_includes_the_floor() -> None:
    qr = _POT.q_rest.detach()[None]
    H = torch.autograd.functional.hessian(lambda z: _POT(z).sum(), qr)[0, :, 0, :]
    Hg = torch.autograd.functional.hessian(lambda z: _POT.g(z).sum(), qr)[0, :, 0, :]
    torch.testing.assert_close(H, Hg + _POT.eps * torch.eye(_D, dtype=F64), rtol=1e-9, atol=1e-12)
    assert np.all(np.linalg.eigvalsh(H.numpy()) >= _POT.eps - 1e-9)


@pytest.mark.parametrize("d", [1, 2])
def test_learned_inertia_obeys_the_energy_balance(d):
    """With M(q) learned, dE/dt = f^T qdot - qdot^T C qdot exactly (paper App. A.2),
    which checks the Coriolis terms d(M qdot)/dq qdot - dT/dq."""
    torch.manual_seed(1)
    lag = Lagrangian(d, mass="learned").eval()
    with torch.no_grad():
        for p in lag.mass_field.parameters():
            p.add_(0.3 * torch.randn_like(p))
    q, v, f = torch.randn(6, d), torch.randn(6, d), torch.randn(6, d)
    a = lag.acceleration(q, v, f)
    q_, v_ = q.clone().requires_grad_(True), v.clone().requires_grad_(True)
    T, V, D = lag.energies(q_, v_)
    gq, gv = torch.autograd.grad((T + V).sum(), [q_, v_])
    dEdt = (gq * v).sum(1) + (gv * a).sum(1)
    torch.testing.assert_close(dEdt, (f * v).sum(1) - 2 * D.detach(), rtol=1e-4, atol=1e-5)
    M = lag.mass_matrix(q)
    assert torch.all(torch.linalg.eigvalsh(M) > 0)
    qs, _ = rollout(lag, q[:2], v[:2], 0.01, 2000)
    assert torch.isfinite(qs).all()
    assert (qs[:, -1] - lag.q_rest).norm(dim=-1).max() < 0.1 * (qs[:, 0] - lag.q_rest).norm(dim=-1).max()
