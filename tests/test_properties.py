"""Property-based tests of the latent dissipative Lagrangian (paper App. A.2, A.1).

Randomly initialised, UNTRAINED models (random seed, ``d`` in {1, 2, 3}, mass
``scalar``/``constant``/``learned``, potential ``convex``/``invex``, hidden
widths (16, 16), random rest state, every weight perturbed away from its tidy
initialisation, random ``init_energy_scales(omega, zeta_floor)``) under
batches of random constant generalized forces (and random non-negative
actuation ``u`` with ``n_u`` in {1, 2}) must satisfy:

a. the state stays bounded: finite, and inside the ball that the loaded
   energy at ``t = 0`` and the quadratic floor of ``V`` allow;
b. the loaded energy ``E_f = T + V - f^T q - e^{s_V} u^T nu(q)`` never
   increases beyond the integration error (paper App. A.2, energy balance
   ``dE_f/dt = -qdot^T C qdot <= -c0 |qdot|^2``);
c. the state converges to the loaded equilibrium of
   :meth:`Lagrangian.loaded_equilibrium` (unique for the convex potential,
   and for any potential without load; an invex potential under load may have
   several, see :func:`_check_converges` and :func:`test_invex_loaded_equilibrium_is_unique`);
d. chart invariance (App. A.1): in the chart ``q' = A q`` the transformed
   Lagrangian ``M' = A^-T M A^-1``, ``C' = A^-T C A^-1``, ``V'(q') = V(A^-1 q')``,
   ``f' = A^-T f`` (Euler-Lagrange solved independently of
   ``Lagrangian.acceleration``, Coriolis terms by autograd) rolls out the mapped
   trajectory, and the loaded equilibria map onto each other.

A *trial* is one (model, constant load) trajectory; every example draws one
model and a batch of ``B`` loads (row 0: no load, a free rollout). Scalar / constant
inertia without actuation roll out on the compiled path; learned inertia and
actuation on the torch path (``fast=False``), with fewer examples and steps
because it is ~400x slower (the compiled path covers them too and is checked
against the torch path in tests/test_fast_rollout.py).

Trial count (asserted in :func:`test_trial_count_and_no_divergence` when the
whole module runs)::

    a+b fast   45 x 10 = 450      a+b torch   10 x 8 =  80
    c   fast   35 x 10 = 350      c   torch    6 x 8 =  48
    d   chart  24 x  8 = 192                          ------
                                                      1120 trials, 0 divergences

Step size. The integrator (paper Eq. 8) is explicit: velocity Verlet is stable
for ``h Omega < 2`` (``Omega^2`` the largest eigenvalue of ``M^-1 d2V_f/dq2``) and,
its velocity-dependent terms being explicit too, for ``h Gamma < 4``
(``Gamma`` the largest eigenvalue of ``M^-1 C``; the velocity of a pure damper
is multiplied by ``(1 - h Gamma / 2)^2`` per step). Every trial uses the video
step ``1/30 s`` unless an a-priori estimate of ``Omega`` and ``Gamma`` over the
region the trial can reach asks for a smaller one: ``h = min(1/30, 1/Omega,
2/Gamma)`` (a factor 2 inside both limits). Both quantities are chart invariant,
so (d) uses the same step in both charts. With the dissipation MLP's weights
perturbed by ~0.5, ``Gamma`` grows like ``|q|^2`` and at ``1/30 s`` the scheme then
does blow up (``h Gamma ~ 30`` was seen): (a-c) state properties of the model
*and* its integrator under this stability condition, not for any step.

Runtime: ~45 s on 2 cores (~55 s with a cold numba cache); torch runs on one thread here
(the ``one_torch_thread`` fixture of ``tests/conftest.py``), which is much faster
than two for these tiny tensors on a loaded machine.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from torch import Tensor

from lagsplat.dynamics.fast import supports_fast
from lagsplat.dynamics.integrators import rollout
from lagsplat.models.lagrangian import Lagrangian

F64 = torch.float64
H_VIDEO = 1.0 / 30.0  # s, the step of a 30 Hz video

# examples per test and loads per example (the trial arithmetic of the module docstring)
N_AB_FAST, B_AB_FAST = 45, 10
N_AB_TORCH, B_AB_TORCH = 10, 8
N_C_FAST, B_C_FAST = 35, 10
N_C_TORCH, B_C_TORCH = 6, 8
N_D, B_D = 24, 8
PLANNED_TRIALS = (
    N_AB_FAST * B_AB_FAST + N_AB_TORCH * B_AB_TORCH + N_C_FAST * B_C_FAST + N_C_TORCH * B_C_TORCH + N_D * B_D
)

TRIALS: Counter = Counter()  # trials run per test (filled as the tests pass)
DIVERGED: Counter = Counter()  # non-finite trajectories per test (must stay 0)
INVEX_ELSEWHERE: Counter = Counter()  # (c) invex trials that settled at another loaded equilibrium


def _settings(n: int):
    return settings(
        max_examples=n, deadline=None, derandomize=True, database=None, suppress_health_check=[HealthCheck.too_slow]
    )


# Small tensors: one torch thread avoids OpenMP hand-offs (10-40x faster on a loaded 2-core machine).
pytestmark = pytest.mark.usefixtures("one_torch_thread")


# ----------------------------------------------------------------------------- scenarios
@dataclass
class Scenario:
    """One random model and a batch of ``B`` constant loads.

    ``q_t [B,d]`` is the loaded equilibrium by construction (``f`` is chosen as
    ``dV/dq(q_t) - b(q_t)^T u e^{s_V}``); ``h`` the step (s).
    """

    model: Lagrangian
    omega: float
    h: float
    q0: Tensor
    v0: Tensor
    f: Tensor
    u: Tensor | None
    q_t: Tensor
    label: str

    @property
    def fast(self) -> bool:
        return supports_fast(self.model)


def _unit_ball(n: int, d: int, gen: torch.Generator) -> Tensor:
    x = torch.randn(n, d, generator=gen, dtype=F64)
    return x / x.norm(dim=-1, keepdim=True) * torch.rand(n, 1, generator=gen, dtype=F64) ** (1.0 / d)


def _loaded_hessian(model: Lagrangian, q: Tensor, f: Tensor, u: Tensor | None) -> Tensor:
    """``d2 V_f / dq2 [N,d,d]`` of the loaded potential (autograd)."""
    with torch.enable_grad():
        x = q.detach().clone().requires_grad_(True)
        (g,) = torch.autograd.grad(model.loaded_potential(x, f, u).sum(), x, create_graph=True)
        H = torch.stack([torch.autograd.grad(g[:, i].sum(), x, retain_graph=True)[0] for i in range(model.d)], 1)
    return 0.5 * (H + H.transpose(1, 2)).detach()


def _loaded_grad(model: Lagrangian, q: Tensor, f: Tensor, u: Tensor | None) -> Tensor:
    with torch.enable_grad():
        x = q.detach().clone().requires_grad_(True)
        (g,) = torch.autograd.grad(model.loaded_potential(x, f, u).sum(), x)
    return g


def _max_eig(M: Tensor, X: Tensor) -> Tensor:
    """Largest (real) eigenvalue of ``M^-1 X`` per batch entry (``M`` SPD, ``X`` symmetric)."""
    return torch.linalg.eigvals(torch.linalg.solve(M, X)).real.amax(-1)


def _rates(model: Lagrangian, q: Tensor, f: Tensor, u: Tensor | None) -> tuple[Tensor, Tensor]:
    """``(Omega [N], Gamma [N])``: ``sqrt(lambda_max(M^-1 d2V_f))`` and ``lambda_max(M^-1 C)`` at ``q``."""
    with torch.no_grad():
        M = model.mass_matrix(q)
        C = model.dissipation_matrix(q)
    K = _loaded_hessian(model, q, f, u)
    return _max_eig(M, K).clamp_min(0.0).sqrt(), _max_eig(M, C)


def _stable_step(model, q0, v0, q_t, f, u, omega, gen, samples: int = 12) -> float:
    """``min(1/30, 1/Omega, 2/Gamma)`` over points the trials can reach (see module docstring).

    Region: per trial, the ball around its equilibrium ``q_t`` of radius
    ``1.5 (|q0 - q_t| + |v0| / omega) + 0.5`` (oscillation amplitude estimate), plus ``q0``.
    """
    B, d = q0.shape
    R = 1.5 * ((q0 - q_t).norm(dim=-1) + v0.norm(dim=-1) / omega) + 0.5
    pts = q_t[:, None, :] + R[:, None, None] * _unit_ball(B * samples, d, gen).reshape(B, samples, d)
    pts = torch.cat([pts, q0[:, None], q_t[:, None]], 1)  # [B, S+2, d]
    S = pts.shape[1]
    fr = f[:, None].expand(B, S, d).reshape(-1, d)
    ur = None if u is None else u[:, None].expand(B, S, u.shape[1]).reshape(-1, u.shape[1])
    Om, Ga = _rates(model, pts.reshape(-1, d), fr, ur)
    return float(min(H_VIDEO, 1.0 / float(Om.max()), 2.0 / float(Ga.max())))


def build_scenario(
    seed: int, d: int, mass: str, potential: str, n_u: int, omega: float, zeta: float, perturb: float, reach: float, B: int
) -> Scenario:
    """A random untrained model (float64, eval) and ``B`` loads with known equilibria ``q_t``."""
    with torch.random.fork_rng():
        torch.manual_seed(seed)
        model = Lagrangian(d, mass=mass, hidden=(16, 16), potential=potential, n_u=n_u).to(F64)
        with torch.no_grad():
            model.potential_hat.q_rest.copy_(torch.randn(d, dtype=F64))
            for p in model.parameters():  # away from the tidy initialisation (zero layers, R = -3, ...)
                p.add_(perturb * torch.randn_like(p))
    model.init_energy_scales(omega, zeta)
    model.eval()
    gen = torch.Generator().manual_seed(seed)
    q_star = model.q_rest.detach()
    q_t = q_star + reach * torch.randn(B, d, generator=gen, dtype=F64)
    q_t[0] = q_star
    u = None
    f = model.potential_grad(q_t, create_graph=False)
    if n_u:
        u = reach * torch.rand(B, n_u, generator=gen, dtype=F64)  # u >= 0 (pressures)
        u[0] = 0.0
        f = f - model.actuation_force(q_t, u).detach()
    f[0] = 0.0  # row 0: free rollout, equilibrium q*
    q0 = q_t + torch.randn(B, d, generator=gen, dtype=F64)
    v0 = 0.5 * omega * torch.randn(B, d, generator=gen, dtype=F64)
    h = _stable_step(model, q0, v0, q_t, f, u, omega, gen)
    label = f"seed={seed} d={d} mass={mass} V={potential} n_u={n_u} omega={omega:.3g} zeta={zeta:.3g} perturb={perturb:.3g} reach={reach:.3g} h={h:.4g}"
    return Scenario(model, omega, h, q0, v0, f, u, q_t, label)


# Hypothesis draws the seed and the discrete choices; the continuous settings are drawn from the
# seed (uniform in their ranges), so that every example is a genuinely random model instead of
# Hypothesis' favourite boundary values (perturb = 0, reach = 0, omega at its minimum, ...).
OMEGA = (2 * math.pi * 0.2, 2 * math.pi * 2.0)  # rad/s: 0.2-2 Hz, filmed at 30 Hz
ZETA = (0.05, 0.5)  # damping ratio of the floor c0 at omega
PERTURB = (0.0, 0.3)  # std of the noise added to every parameter
REACH = (0.0, 1.5)  # std of the loaded equilibria around q*

_seed = st.integers(0, 2**31 - 1)
_d = st.sampled_from([1, 2, 3])
_potential = st.sampled_from(["convex", "invex"])


def random_scenario(seed: int, d: int, mass: str, potential: str, n_u: int, B: int, omega=OMEGA, zeta=ZETA) -> Scenario:
    """:func:`build_scenario` with ``omega, zeta, perturb, reach`` uniform in their ranges (from ``seed``)."""
    rng = np.random.default_rng(seed)
    return build_scenario(
        seed, d, mass, potential, n_u, float(rng.uniform(*omega)), float(rng.uniform(*zeta)), float(rng.uniform(*PERTURB)), float(rng.uniform(*REACH)), B
    )


def _fast_family(B: int):
    """Scalar / constant inertia, no actuation: the compiled path."""
    return st.builds(random_scenario, _seed, _d, st.sampled_from(["scalar", "constant"]), _potential, st.just(0), st.just(B))


@st.composite
def _torch_family(draw, B: int, **ranges):
    """Learned inertia and/or actuation, rolled out on the torch path (the compiled path is checked against it
    step by step in tests/test_fast_rollout.py)."""
    mass = draw(st.sampled_from(["scalar", "constant", "learned"]))
    n_u = draw(st.sampled_from([1, 2] if mass != "learned" else [0, 1, 2]))
    return random_scenario(draw(_seed), draw(_d), mass, draw(_potential), n_u, B, **ranges)


def _roll(sc: Scenario, n: int, fast: bool | None = None) -> tuple[Tensor, Tensor]:
    q, v = rollout(sc.model, sc.q0, sc.v0, sc.h, n, f_ext=sc.f, u=sc.u, fast=fast)
    assert q.dtype == F64
    return q, v


def _count_finite(name: str, sc: Scenario, q: Tensor, v: Tensor) -> None:
    ok = torch.isfinite(q).all(-1).all(-1) & torch.isfinite(v).all(-1).all(-1)
    DIVERGED[name] += int((~ok).sum())
    assert ok.all(), f"{int((~ok).sum())} of {len(ok)} trajectories diverged: {sc.label}"


def _loaded_energy(sc: Scenario, q: Tensor, v: Tensor) -> Tensor:
    """``E_f [B,n]`` along trajectories ``[B,n,d]``."""
    B, n, d = q.shape
    fr = sc.f[:, None].expand(B, n, d).reshape(-1, d)
    ur = None if sc.u is None else sc.u[:, None].expand(B, n, sc.u.shape[1]).reshape(-1, sc.u.shape[1])
    with torch.no_grad():
        return sc.model.loaded_energy(q.reshape(-1, d), v.reshape(-1, d), fr, ur).reshape(B, n)


def _energy_slack(h: float, Omega: float) -> float:
    """Relative rise of ``E_f - E_f*`` allowed between two times (integration error, O(h^2)).

    Velocity Verlet conserves a modified energy exactly for the harmonic
    oscillator, ``1/2 v^2 + 1/2 w^2 (1 - (h w)^2 / 4) x^2``, so along one orbit the
    true energy swings by the factor ``1 / (1 - (h w)^2 / 4)``: it can rise by
    ``(h w)^2 / (4 - (h w)^2)`` relative to an earlier value, and no more
    (backward error analysis: ``|E - E_modified| = O(h^2 Omega^2) E`` for a
    nonlinear potential whose local frequencies stay below ``Omega``). The
    dissipation only removes energy at leading order. We allow twice the
    harmonic swing, with ``Omega`` the largest local frequency measured on the
    visited states.
    """
    x = h * Omega
    assert x < 2.0, f"step outside the Verlet stability region (h Omega = {x:.2f})"
    return 2.0 * x * x / (4.0 - x * x)


def _mass_floor(model: Lagrangian) -> float:
    """Lower bound of ``lambda_min(M)``: ``m`` (scalar), ``m 0.1 / 1.1`` (constant, learned)."""
    m = math.exp(float(model.s_M.detach()))
    return m if model.mass_kind == "scalar" else m * 0.1 / 1.1


def _quadratic_floor(model: Lagrangian) -> float:
    """``mu`` with ``V(q) >= mu / 2 |q - q*|^2`` (``e^{s_V} eps``, times ``(1 - lip)^(2 blocks)`` for invex)."""
    pot = model.potential_hat
    mu = math.exp(float(model.s_V.detach())) * pot.eps
    if pot.phi is not None:  # |phi(x) - phi(y)| >= (1 - lip)^blocks |x - y|
        mu *= (1.0 - pot.phi.lip) ** (2 * len(pot.phi.l1))
    return mu


# ----------------------------------------------------------------------------- (a) + (b)
def _check_bounded_and_dissipative(name: str, sc: Scenario, n: int, fast: bool | None = None) -> None:
    model, d = sc.model, sc.model.d
    q, v = _roll(sc, n, fast)
    _count_finite(name, sc, q, v)
    B = q.shape[0]
    E = _loaded_energy(sc, q, v)  # [B,n]
    E_star = model.loaded_potential(sc.q_t, sc.f, sc.u).detach()  # the minimum of V_f (q_t is the equilibrium)
    dE = E - E_star[:, None]
    # Omega on the visited states (every 10th), for the O(h^2) slack
    idx = torch.arange(0, n, 10)
    qs = q[:, idx].reshape(-1, d)
    k = len(idx)
    Om, _ = _rates(
        model, qs, sc.f[:, None].expand(B, k, d).reshape(-1, d), None if sc.u is None else sc.u[:, None].expand(B, k, -1).reshape(-1, sc.u.shape[1])
    )
    slack = _energy_slack(sc.h, float(Om.max()))
    with torch.no_grad():
        T, V, _ = model.energies(q.reshape(-1, d), v.reshape(-1, d))
    mag = 1.0 + E_star.abs()[:, None] + T.reshape(B, n).abs() + V.reshape(B, n).abs() + (sc.f[:, None] * q).sum(-1).abs()
    atol = 1e-11 * mag.amax(1, keepdim=True)  # round-off of E_f in float64
    # (b) E_f never rises above an earlier value by more than the integration error
    assert (dE >= -atol).all(), f"below the minimum of V_f: {sc.label}"
    running_min = torch.cummin(dE, 1).values
    excess = dE - (1.0 + slack) * running_min - atol
    assert (excess <= 0).all(), f"E_f rose by {float((dE - running_min).max()):.3e} > slack {slack:.2e}: {sc.label}"
    moving = dE[:, 0] > 1e3 * atol[:, 0]
    assert (dE[moving, -1] < dE[moving, 0]).all(), f"no energy dissipated: {sc.label}"  # C >= c0 I, c0 > 0
    # (a) bounded: E_f(t) <= E_cap, and V_f(q) >= V_f(q*) - |g| r + mu/2 r^2 (r = |q - q*|), with
    # g = f + e^{s_V} b(q*)^T u (nu concave: -u^T nu(q) >= its tangent at q*); T <= E_cap - E_f*.
    E_cap = E_star + (1.0 + slack) * dE[:, 0] + atol[:, 0]
    mu = _quadratic_floor(model)
    q_star = model.q_rest.detach()[None].expand(B, d)
    g = sc.f.clone()
    if sc.u is not None:
        g = g + model.actuation_force(q_star, sc.u).detach()
    Vf_star = model.loaded_potential(q_star, sc.f, sc.u).detach()
    gn = g.norm(dim=-1)
    r_max = (gn + torch.sqrt(gn**2 + 2.0 * mu * (E_cap - Vf_star).clamp_min(0.0))) / mu
    r = (q - q_star[:, None]).norm(dim=-1)
    assert (r.amax(1) <= r_max * (1 + 1e-9)).all(), f"|q - q*| = {r.amax(1)} beyond {r_max}: {sc.label}"
    if model.potential_kind == "convex":  # V_f strongly convex with modulus mu: |q - q_t| <= sqrt(2 (E_cap - E_f*) / mu)
        r_t = (q - sc.q_t[:, None]).norm(dim=-1)
        assert (r_t.amax(1) <= torch.sqrt(2.0 * (E_cap - E_star) / mu) * (1 + 1e-9) + 1e-12).all(), sc.label
    v_max = torch.sqrt(2.0 * (E_cap - E_star) / _mass_floor(model))
    assert (v.norm(dim=-1).amax(1) <= v_max * (1 + 1e-9) + 1e-12).all(), f"|qdot| beyond {v_max}: {sc.label}"
    TRIALS[name] += B


@_settings(N_AB_FAST)
@given(sc=_fast_family(B_AB_FAST))
def test_ab_fast_rollouts_stay_bounded_and_loaded_energy_never_increases(sc: Scenario) -> None:
    """(a) and (b) on the compiled path, 900 steps (30 s of video at 30 Hz)."""
    assert sc.fast
    _check_bounded_and_dissipative("ab_fast", sc, 901)


@_settings(N_AB_TORCH)
@given(sc=_torch_family(B_AB_TORCH))
def test_ab_torch_rollouts_stay_bounded_and_loaded_energy_never_increases(sc: Scenario) -> None:
    """(a) and (b) for learned inertia / actuation on the torch path (``fast=False``), 150 steps."""
    _check_bounded_and_dissipative("ab_torch", sc, 151, fast=False)


# ----------------------------------------------------------------------------- (c)
def _slowest_rate(model: Lagrangian, q: Tensor, f: Tensor, u: Tensor | None) -> float:
    """Slowest decay rate ``min -Re(lambda)`` (1/s) of the linearisation at the equilibria ``q [B,d]``."""
    with torch.no_grad():
        M = model.mass_matrix(q).numpy()
        C = model.dissipation_matrix(q).numpy()
    K = _loaded_hessian(model, q, f, u).numpy()
    d = q.shape[1]
    rates = []
    for b in range(q.shape[0]):
        A = np.zeros((2 * d, 2 * d))
        A[:d, d:] = np.eye(d)
        A[d:, :d] = -np.linalg.solve(M[b], K[b])
        A[d:, d:] = -np.linalg.solve(M[b], C[b])
        rates.append(-np.linalg.eigvals(A).real.max())
    return float(min(rates))


def _check_converges(name: str, sc: Scenario, max_steps: int, n_tau: float = 30.0, fast: bool | None = None) -> None:
    """Roll out ``n_tau`` time constants of the slowest linearised mode at ``q_t`` (at most ``max_steps``)."""
    model = sc.model
    q_eq = model.loaded_equilibrium(sc.f, sc.u)  # damped Newton, |grad V_f| <= 1e-6 (1 + |f|) (+ actuation)
    rate = _slowest_rate(model, sc.q_t, sc.f, sc.u)
    assert rate > 0, sc.label
    n = int(min(max_steps, math.ceil(n_tau / (rate * sc.h)))) + 1
    q, v = _roll(sc, n, fast)
    _count_finite(name, sc, q, v)
    T_end = (n - 1) * sc.h
    scale = 1.0 + (sc.q0 - sc.q_t).norm(dim=-1) + sc.v0.norm(dim=-1) / sc.omega
    # converged at least at the linearised rate (100 covers the non-linear transient), to 1e-6 at most
    tol = scale * max(1e-6, 100.0 * math.exp(-rate * T_end))
    q_end, v_end = q[:, -1], v[:, -1]
    loaded = (sc.f != 0).any(-1)
    if sc.u is not None:
        loaded |= (sc.u != 0).any(-1)
    # q_t is the loaded equilibrium by construction; it is the only one for the convex potential
    # (V_f strongly convex) and without load (q* is the only stationary point of the invex V).
    # With load, V - f^T q need not have a single stationary point for the invex potential
    # (test_invex_loaded_equilibrium_is_unique): the trajectory may settle at another one.
    unique = ~loaded if model.potential_kind == "invex" else torch.ones_like(loaded)
    err = (q_end - sc.q_t).norm(dim=-1)
    elsewhere = ~unique & (err > tol)
    assert (err[~elsewhere] <= tol[~elsewhere]).all(), f"|q_end - q_eq| = {err.tolist()} > {tol.tolist()} after {n} steps: {sc.label}"
    if elsewhere.any():  # it must still have settled at a loaded equilibrium: a stationary point, local minimum of V_f
        INVEX_ELSEWHERE[name] += int(elsewhere.sum())
        fe, ue = sc.f[elsewhere], None if sc.u is None else sc.u[elsewhere]
        g = _loaded_grad(model, q_end[elsewhere], fe, ue)
        assert (g.norm(dim=-1) <= 1e-6 * (1 + fe.norm(dim=-1))).all(), sc.label
        assert (torch.linalg.eigvalsh(_loaded_hessian(model, q_end[elsewhere], fe, ue))[:, 0] >= -1e-9).all(), sc.label
    assert (v_end.norm(dim=-1) <= sc.omega * tol).all(), sc.label
    # ... and it is the equilibrium that Lagrangian.loaded_equilibrium finds: no load -> q* exactly;
    # convex -> within |grad V_f(q_eq)| / mu of q_t (strong convexity, modulus mu = e^{s_V} eps);
    # invex with load -> a stationary point of V_f (maybe not q_t, see above).
    torch.testing.assert_close(q_eq[~loaded], sc.q_t[~loaded], rtol=0, atol=1e-12)
    g_eq = _loaded_grad(model, q_eq, sc.f, sc.u).norm(dim=-1)
    assert (g_eq <= 1e-5 * (1 + sc.f.norm(dim=-1))).all(), sc.label
    if model.potential_kind == "convex":
        bound = g_eq / _quadratic_floor(model) + 1e-12
        assert ((q_eq - sc.q_t).norm(dim=-1) <= bound).all(), sc.label
        assert ((q_end - q_eq).norm(dim=-1) <= tol + bound).all(), sc.label
    TRIALS[name] += len(q_end)


@_settings(N_C_FAST)
@given(sc=_fast_family(B_C_FAST))
def test_c_fast_rollouts_converge_to_the_loaded_equilibrium(sc: Scenario) -> None:
    """(c) on the compiled path: 30 slowest-mode time constants (at most 40000 steps)."""
    assert sc.fast
    _check_converges("c_fast", sc, max_steps=40_000)


@_settings(N_C_TORCH)
@given(sc=_torch_family(B_C_TORCH, zeta=(0.3, 0.5), omega=(2 * math.pi * 0.5, 2 * math.pi * 2.0)))
def test_c_torch_rollouts_converge_to_the_loaded_equilibrium(sc: Scenario) -> None:
    """(c) for learned inertia / actuation on the torch path (``fast=False``): at most 600 steps, so well-damped models only."""
    _check_converges("c_torch", sc, max_steps=600, fast=False)


# ----------------------------------------------------------------------------- (d)
class ChartModel:
    """The Lagrangian of ``model`` in the chart ``q' = A q`` (rows: ``q' = q A^T``), paper App. A.1.

    ``T' = 1/2 qdot'^T M'(q') qdot'`` with ``M' = A^-T M(A^-1 q') A^-1``,
    ``C' = A^-T C A^-1``, ``V'(q') = V(A^-1 q')``, actuation potential
    ``e^{s_V} u^T nu(A^-1 q')``. :meth:`acceleration` solves its Euler-Lagrange
    equation from these ingredients alone (Coriolis terms by autograd), not
    through ``model.acceleration``:

        ``M' qddot' = dL'/dq' - (d(M' qdot')/dq') qdot' - C' qdot' + f'``,  ``L' = T' - V' + e^{s_V} u^T nu``.
    """

    def __init__(self, model: Lagrangian, A: Tensor) -> None:
        self.model, self.A, self.Ainv = model, A, torch.linalg.inv(A)

    def to_model(self, qp: Tensor) -> Tensor:
        """``q = A^-1 q'`` (rows)."""
        return qp @ self.Ainv.T

    def mass_matrix(self, qp: Tensor) -> Tensor:
        return self.Ainv.T @ self.model.mass_matrix(self.to_model(qp)) @ self.Ainv

    def dissipation_matrix(self, qp: Tensor) -> Tensor:
        return self.Ainv.T @ self.model.dissipation_matrix(self.to_model(qp)) @ self.Ainv

    def potential(self, qp: Tensor, u: Tensor | None = None) -> Tensor:
        """``V'(q') - e^{s_V} u^T nu(A^-1 q')`` ``[B]``."""
        q = self.to_model(qp)
        V = self.model.potential(q)
        if u is not None:
            V = V - torch.exp(self.model.s_V) * (self.model.actuation(q) * u).sum(-1)
        return V

    def acceleration(self, qp: Tensor, vp: Tensor, fp: Tensor | None = None, u: Tensor | None = None) -> Tensor:
        d = qp.shape[1]
        with torch.enable_grad():
            x = qp.detach().requires_grad_(True)
            M = self.mass_matrix(x)
            p = torch.einsum("bij,bj->bi", M, vp)
            lag = 0.5 * (p * vp).sum() - self.potential(x, u).sum()
            (dL,) = torch.autograd.grad(lag, x, retain_graph=True)
            # d(M' qdot')/dq' (zero, i.e. unused, for a constant inertia)
            rows = [
                torch.autograd.grad(p[:, i].sum(), x, retain_graph=True, allow_unused=True, materialize_grads=True)[0]
                for i in range(d)
            ]
            coriolis = torch.einsum("bij,bj->bi", torch.stack(rows, 1), vp)
        force = dL - coriolis - torch.einsum("bij,bj->bi", self.dissipation_matrix(qp).detach(), vp)
        if fp is not None:
            force = force + fp
        return torch.linalg.solve(M.detach(), force.detach().unsqueeze(-1)).squeeze(-1)


def _random_chart(d: int, gen: torch.Generator) -> Tensor:
    """``A = Q1 diag(s) Q2``, ``Q`` random orthogonal (reflections included), ``s`` in [1/2, 2]: cond(A) <= 4."""
    Q1, _ = torch.linalg.qr(torch.randn(d, d, generator=gen, dtype=F64))
    Q2, _ = torch.linalg.qr(torch.randn(d, d, generator=gen, dtype=F64))
    s = torch.exp(torch.empty(d, dtype=F64).uniform_(-math.log(2.0), math.log(2.0), generator=gen))
    return Q1 @ torch.diag(s) @ Q2


@st.composite
def _any_family(draw, B: int):
    """Every mass kind, with actuation on half of the draws."""
    mass = draw(st.sampled_from(["scalar", "constant", "learned"]))
    n_u = draw(st.sampled_from([0, 0, 1, 2]))
    return random_scenario(draw(_seed), draw(_d), mass, draw(_potential), n_u, B)


@_settings(N_D)
@given(sc=_any_family(B_D), chart_seed=_seed)
def test_d_rollouts_and_equilibria_are_chart_invariant(sc: Scenario, chart_seed: int) -> None:
    """(d): ``q'(t) = A q(t)`` over 60 steps, ``E_f' = E_f``, and ``A q_eq`` is the equilibrium in the new chart."""
    model, d = sc.model, sc.model.d
    A = _random_chart(d, torch.Generator().manual_seed(chart_seed))
    chart = ChartModel(model, A)
    fp = sc.f @ chart.Ainv  # f' = A^-T f (rows)
    n = 61
    q, v = _roll(sc, n)  # compiled path when supported
    qp, vp = rollout(chart, sc.q0 @ A.T, sc.v0 @ A.T, sc.h, n, f_ext=fp, u=sc.u)  # torch path, other chart
    _count_finite("d", sc, q, v)
    _count_finite("d", sc, qp, vp)
    scale = 1.0 + float((q @ A.T).abs().max())
    torch.testing.assert_close(qp, q @ A.T, rtol=0, atol=1e-8 * scale)
    torch.testing.assert_close(vp, v @ A.T, rtol=0, atol=1e-8 * (scale + float((v @ A.T).abs().max())))
    # the energy is a scalar: same value in both charts
    with torch.no_grad():
        Mp = chart.mass_matrix(qp[:, -1])
        Ep = 0.5 * torch.einsum("bi,bij,bj->b", vp[:, -1], Mp, vp[:, -1]) + chart.potential(qp[:, -1], sc.u) - (fp * qp[:, -1]).sum(-1)
        E = model.loaded_energy(q[:, -1], v[:, -1], sc.f, sc.u)
    torch.testing.assert_close(Ep, E, rtol=1e-9, atol=1e-12)
    # loaded equilibria map onto each other: the residual generalized force at A q_eq in the new
    # chart is A^-T times the one at q_eq (zero up to the Newton tolerance of loaded_equilibrium)
    q_eq = model.loaded_equilibrium(sc.f, sc.u)
    qp_eq = q_eq @ A.T
    res_p = torch.einsum("bij,bj->bi", chart.mass_matrix(qp_eq).detach(), chart.acceleration(qp_eq, torch.zeros_like(q_eq), fp, sc.u))
    res = -_loaded_grad(model, q_eq, sc.f, sc.u)
    fscale = 1.0 + sc.f.norm(dim=-1, keepdim=True)
    assert (res.norm(dim=-1, keepdim=True) <= 1e-5 * fscale).all(), sc.label
    torch.testing.assert_close(res_p / fscale, (res @ chart.Ainv) / fscale, rtol=0, atol=1e-10)
    TRIALS["d"] += len(q)


# ----------------------------------------------------------------------------- invex caveat and totals
@pytest.mark.xfail(strict=True, reason="V - f^T q can have several stationary points for the invex potential")
def test_invex_loaded_equilibrium_is_unique() -> None:
    """Counter-example to "coercive with one stationary point dV/dq = f for the invex one"
    (Lagrangian.loaded_potential): invexity of ``V`` (``q*`` its only stationary point) is not kept
    by adding the linear load ``-f^T q``. Along a 1-D ray ``dV/dq`` is not monotone where
    ``Dphi`` bends (``d2V/dq2 < 0`` at ``q - q* ~ 5..15`` here), so for ``f`` between the values at
    its local max and min, ``dV/dq = f`` has three roots: two stable loaded equilibria and a saddle.
    Free rollouts from either side settle at different ones. (c) therefore requires uniqueness
    only for the convex potential and for unloaded invex trials."""
    sc = build_scenario(12, 1, "scalar", "invex", 0, 5.0, 0.2, 0.3, 0.0, 1)
    model = sc.model
    q_star = float(model.q_rest.detach())
    f = torch.tensor([[30.14]], dtype=F64)
    near = model.loaded_equilibrium(f)
    far = model.loaded_equilibrium(f, q0=torch.tensor([[q_star + 60.0]], dtype=F64))
    for q in (near, far):
        assert float(_loaded_grad(model, q, f, None).abs().max()) < 1e-5
    assert float((near - far).abs().max()) < 1e-3, f"two loaded equilibria: q - q* = {float(near) - q_star:.3f} and {float(far) - q_star:.3f}"


def test_trial_count_and_no_divergence() -> None:
    """>= 1000 random (model, load) trials, none diverged (checked when the whole module ran)."""
    assert PLANNED_TRIALS >= 1000
    names = {"ab_fast", "ab_torch", "c_fast", "c_torch", "d"}
    if set(TRIALS) != names:
        pytest.skip(f"only part of the module ran ({sorted(TRIALS)})")
    total = sum(TRIALS.values())
    print(f"\nproperty trials: {dict(TRIALS)} = {total}; divergences: {sum(DIVERGED.values())}; invex settled elsewhere: {dict(INVEX_ELSEWHERE)}")
    assert sum(DIVERGED.values()) == 0
    assert total >= 1000, dict(TRIALS)
