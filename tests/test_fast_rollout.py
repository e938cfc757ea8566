"""Tests of the compiled rollout path (lagsplat.dynamics.fast) against the torch path
(lagsplat.dynamics.integrators.rollout with fast=False): same velocity-Verlet scheme,
same model, agreement to round-off, automatic dispatch, export cache, fall-backs."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from lagsplat.dynamics.fast import (
    cached_export,
    export_model,
    fast_acceleration,
    fast_potential_grad,
    fast_rollout,
    supports_fast,
)
from lagsplat.dynamics.integrators import actuation_schedule, rollout, verlet_step
from lagsplat.evaluate.krauss_rollouts import rollout_zoh
from lagsplat.models.inertia import DecoderInertia
from lagsplat.models.lagrangian import Lagrangian

F64 = torch.float64
H = 1.0 / 30.0


# The torch reference rollouts work on tiny tensors: one thread is faster on a loaded 2-core machine.
pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _model(d: int, mass: str = "scalar", potential: str = "convex", seed: int = 0, perturb: float = 0.3, dtype=F64, hidden=(16, 16), **kw) -> Lagrangian:
    """Untrained model away from its tidy initialisation, oscillating at ~1 Hz."""
    with torch.random.fork_rng():
        torch.manual_seed(seed)
        model = Lagrangian(d, mass=mass, potential=potential, hidden=hidden, **kw).to(dtype)
        with torch.no_grad():
            model.potential_hat.q_rest.copy_(torch.randn(d, dtype=dtype))
            for p in model.parameters():
                p.add_(perturb * torch.randn_like(p))
    model.init_energy_scales(2 * math.pi * 1.0, 0.1)
    return model.eval()


def _state(model: Lagrangian, B: int, seed: int, dtype=F64):
    g = torch.Generator().manual_seed(seed)
    q0 = model.q_rest.detach() + torch.randn(B, model.d, generator=g, dtype=dtype)
    v0 = 3.0 * torch.randn(B, model.d, generator=g, dtype=dtype)
    return q0, v0


def _close(a: torch.Tensor, b: torch.Tensor, rel: float) -> None:
    """``max |a - b| < rel * state scale``."""
    scale = max(float(b.abs().max()), 1.0)
    err = float((a - b).abs().max())
    assert err < rel * scale, f"max abs diff {err:.3e} vs scale {scale:.3e}"


@pytest.mark.parametrize("d", [1, 2, 4])
@pytest.mark.parametrize("mass", ["scalar", "constant"])
@pytest.mark.parametrize("potential", ["convex", "invex"])
def test_fast_rollout_matches_torch_rollout(d: int, mass: str, potential: str) -> None:
    model = _model(d, mass, potential, seed=10 * d + (mass == "constant") + 2 * (potential == "invex"))
    assert supports_fast(model)
    q0, v0 = _state(model, 3, seed=d)
    g = torch.Generator().manual_seed(100 + d)
    f = 5.0 * torch.randn(3, d, generator=g, dtype=F64)
    n = 301  # 10 s
    for f_ext in (None, f):
        qt, vt = rollout(model, q0, v0, H, n, f_ext=f_ext, fast=False)
        qf, vf = rollout(model, q0, v0, H, n, f_ext=f_ext, fast=True)
        assert qf.shape == vf.shape == (3, n, d) and qf.dtype == F64
        assert torch.equal(qf[:, 0], q0) and torch.equal(vf[:, 0], v0)
        _close(qf, qt, 1e-4)
        _close(vf, vt, 1e-4)
        _close(qf, qt, 1e-9)  # float64 on both sides: agreement to round-off
        # the default (fast=None) dispatches to the compiled path: bit-identical to fast=True
        qa, va = rollout(model, q0, v0, H, n, f_ext=f_ext)
        assert torch.equal(qa, qf) and torch.equal(va, vf)
    # a [1,d] force broadcasts over the batch like on the torch path
    qt, _ = rollout(model, q0, v0, H, 50, f_ext=f[:1], fast=False)
    qf, _ = rollout(model, q0, v0, H, 50, f_ext=f[:1], fast=True)
    _close(qf, qt, 1e-9)


@pytest.mark.parametrize("potential", ["convex", "invex"])
def test_fast_kernels_match_autograd(potential: str) -> None:
    """Hand-written backprop (ICNN, i-ResNet VJP, ELU/softplus derivatives) against autograd,
    with deeper / uneven hidden widths and large pre-activations (softplus threshold)."""
    for hidden in [(16, 16), (7,), (5, 9, 6)]:
        model = _model(3, "constant", potential, seed=len(hidden), perturb=0.5, hidden=hidden)
        fm = export_model(model)
        g = torch.Generator().manual_seed(1)
        q = model.q_rest.detach() + 4.0 * torch.randn(16, 3, generator=g, dtype=F64)
        q[-1] += 40.0  # far out: softplus / ELU saturated
        v = torch.randn(16, 3, generator=g, dtype=F64)
        f = torch.randn(16, 3, generator=g, dtype=F64)
        np.testing.assert_allclose(fast_potential_grad(fm, q), model.potential_grad(q, create_graph=False).numpy(), rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(fast_acceleration(fm, q, v, f), model.acceleration(q, v, f).detach().numpy(), rtol=1e-10, atol=1e-12)
        # the anchor: V has zero gradient at q*
        assert np.abs(fast_potential_grad(fm, model.q_rest.detach()[None])).max() < 1e-12


def test_float32_model_rolls_out_in_float32() -> None:
    model = _model(2, "constant", "invex", seed=3, dtype=torch.float32)
    q0, v0 = _state(model, 2, seed=4, dtype=torch.float32)
    qt, vt = rollout(model, q0, v0, H, 301, fast=False)
    qf, vf = rollout(model, q0, v0, H, 301)
    assert qf.dtype == vf.dtype == torch.float32
    _close(qf, qt, 1e-4)  # float64 inside the kernel vs float32 torch: float32 round-off
    _close(vf, vt, 1e-4)


def test_1000_s_rollout_at_30_hz_settles() -> None:
    """A 1000 s free rollout at d = 1 (default widths (64, 64)) stays finite and settles at rest.

    Its speed is measured by ``python benchmarks/rollout.py`` (a timing is no unit-test assertion)."""
    model = _model(1, "scalar", "convex", seed=0, hidden=(64, 64))
    q0, v0 = _state(model, 1, seed=0)
    q, _ = rollout(model, q0, v0, H, 30_001)
    assert torch.isfinite(q).all()
    assert float((q[0, -1] - model.q_rest.detach()).abs().max()) < 1e-6  # settled at rest after 1000 s


def test_export_is_cached_and_invalidated_by_an_optimizer_step() -> None:
    model = _model(2, "constant", "invex", seed=5)
    fm = cached_export(model)
    assert cached_export(model) is fm  # no re-export while nothing changed
    q0, v0 = _state(model, 2, seed=6)
    q_before, _ = rollout(model, q0, v0, H, 100)
    assert cached_export(model) is fm
    for opt in (torch.optim.Adam(model.parameters(), lr=0.05), torch.optim.AdamW(model.parameters(), lr=0.05, fused=True)):
        # fused AdamW does not bump the parameters' autograd version counters: the cache compares values
        model.train()
        q1, v1 = verlet_step(model, q0, v0, H)
        model.zero_grad()
        (q1.pow(2).sum() + v1.pow(2).sum()).backward()
        opt.step()
        model.eval()
        fm_new = cached_export(model)
        assert fm_new is not fm
        fm = fm_new
        q_fast, _ = rollout(model, q0, v0, H, 100)
        q_torch, _ = rollout(model, q0, v0, H, 100, fast=False)
        _close(q_fast, q_torch, 1e-9)
        assert float((q_fast - q_before).abs().max()) > 1e-6  # the new weights are used
    # writes through .data (no version bump) and buffer / setting changes also invalidate
    with torch.no_grad():
        model.potential_hat.g.out.data.add_(0.1)
    assert cached_export(model) is not fm
    fm = cached_export(model)
    model.c0 = 2.0
    fm2 = cached_export(model)
    assert fm2 is not fm and fm2.c0 == 2.0


def test_unsupported_models_fall_back_to_torch() -> None:
    decoder = _model(2, "decoder", seed=7, inertia=DecoderInertia(8, 2))  # the decoder-induced inertia is not compiled
    q0, v0 = _state(decoder, 2, seed=9)
    assert not supports_fast(decoder)
    with pytest.raises(ValueError, match="does not support"):
        export_model(decoder)
    with pytest.raises(ValueError, match="fast=True"):
        rollout(decoder, q0, v0, H, 5, fast=True)
    q_auto, v_auto = rollout(decoder, q0, v0, H, 40)
    q_torch, v_torch = rollout(decoder, q0, v0, H, 40, fast=False)
    assert torch.equal(q_auto, q_torch) and torch.equal(v_auto, v_torch)
    # time-dependent forces and training mode take the torch path on supported models too
    model = _model(1, "scalar", seed=10)
    q0, v0 = _state(model, 2, seed=11)

    def force(t: float) -> torch.Tensor:
        return torch.full((2, 1), math.sin(t), dtype=F64)

    assert torch.equal(rollout(model, q0, v0, H, 20, f_ext=force)[0], rollout(model, q0, v0, H, 20, f_ext=force, fast=False)[0])
    with pytest.raises(ValueError, match="callable"):
        rollout(model, q0, v0, H, 5, f_ext=force, fast=True)
    model.train()
    assert torch.equal(rollout(model, q0, v0, H, 10)[0], rollout(model, q0, v0, H, 10, fast=False)[0])
    with pytest.raises(ValueError, match="training"):
        rollout(model, q0, v0, H, 5, fast=True)
    model.eval()
    with pytest.raises(ValueError, match="actuation"):
        fast_rollout(export_model(model), q0.numpy(), v0.numpy(), H, 5, u=np.zeros((2, 1)))
    # not a Lagrangian (any object with acceleration): torch path
    assert not supports_fast(object())


def test_non_finite_trajectories_stay_nan() -> None:
    """Like the torch path, a trajectory that turns non-finite is NaN from then on; others are unaffected."""
    model = _model(1, "scalar", seed=12)
    q0 = model.q_rest.detach() + torch.tensor([[0.5], [0.5], [float("nan")]], dtype=F64)
    v0 = torch.zeros(3, 1, dtype=F64)
    f = torch.tensor([[0.0], [float("inf")], [0.0]], dtype=F64)
    q, v = rollout(model, q0, v0, H, 20, f_ext=f)
    assert torch.isfinite(q[0]).all() and torch.isfinite(v[0]).all()
    for b in (1, 2):
        assert torch.isnan(q[b, 1:]).all() and torch.isnan(v[b, 1:]).all()
    qt, _ = rollout(model, q0, v0, H, 20, f_ext=f, fast=False)
    torch.testing.assert_close(q[0], qt[0], rtol=0, atol=1e-12)
    assert not torch.isfinite(qt[1:, 1:]).any()
    # blow-up by an unstable step (h Omega >> 2): NaN from the first non-finite state on
    qb, vb = rollout(model, q0[:1], v0[:1], 5.0, 400)
    bad = ~(torch.isfinite(qb[0]).all(-1) & torch.isfinite(vb[0]).all(-1))
    assert bad.any()
    first = int(bad.nonzero()[0])
    assert torch.isnan(qb[0, first:]).all() and torch.isnan(vb[0, first:]).all()


@pytest.mark.parametrize(("d", "mass", "n_u", "potential"), [(2, "learned", 0, "convex"), (3, "learned", 2, "invex"), (1, "scalar", 1, "convex"), (4, "constant", 3, "convex"), (4, "learned", 4, "convex")])
def test_learned_inertia_and_actuation_match_torch(d: int, mass: str, n_u: int, potential: str) -> None:
    """The compiled velocity terms of a learned M(q) (forward-mode dM/dq) and the actuation Jacobian of the concave
    map (paper Eq. 6, 7) against autograd: accelerations, rollouts under a constant, a scheduled and a held pressure."""
    model = _model(d, mass, potential, seed=20 + d + n_u, perturb=0.15, n_u=n_u)
    assert supports_fast(model)
    fm = export_model(model)
    g = torch.Generator().manual_seed(d + n_u)
    q = model.q_rest.detach() + 2.0 * torch.randn(16, d, generator=g, dtype=F64)
    v, f = 2.0 * torch.randn(16, d, generator=g, dtype=F64), torch.randn(16, d, generator=g, dtype=F64)
    u = torch.rand(16, n_u, generator=g, dtype=F64) if n_u else None
    np.testing.assert_allclose(fast_acceleration(fm, q, v, f, u), model.acceleration(q, v, f, u=u).detach().numpy(), rtol=1e-10, atol=1e-12)
    q0, v0 = _state(model, 2, seed=d)
    n = 151
    U = torch.rand(2, n + 5, n_u, generator=g, dtype=F64)
    schedules = [None] if not n_u else [U[:, 0], actuation_schedule(U.numpy(), H)]
    for sched in schedules:
        qt, vt = rollout(model, q0, v0, H, n, u=sched, fast=False)
        qf, vf = rollout(model, q0, v0, H, n, u=sched)  # dispatched to the compiled path
        assert qf.dtype == F64
        _close(qf, qt, 1e-9)
        _close(vf, vt, 1e-9)
    if n_u:  # the soft-robot protocol's zero-order hold: step i holds P[:, i] at both evaluations
        m = 61  # 2 s: a random learned inertia can drive a held, jumping pressure off to infinity later
        P = 0.3 * U[:, : m - 1].numpy()
        q, vq, ref = q0, v0, [q0]
        for i in range(m - 1):
            q, vq = verlet_step(model, q, vq, H, u=torch.as_tensor(P[:, i]))
            ref.append(q.detach())
        np.testing.assert_allclose(rollout_zoh(model, q0.numpy(), v0.numpy(), H, m, P), torch.stack(ref, 1).numpy(), rtol=1e-9, atol=1e-9)
    with pytest.raises(ValueError, match="actuation"):
        fast_rollout(fm, q0.numpy(), v0.numpy(), H, 5, u=np.zeros((2, n_u + 1)))
