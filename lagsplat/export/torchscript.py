"""The identified model's terms as TorchScript files, for users in torch without lagsplat (paper Eq. 6-7).

Each file is a traced float64 module of a copy of the :class:`~lagsplat.models.lagrangian.Lagrangian`:

* ``M.pt``: ``q [B,d] -> M(q) [B,d,d]``, the inertia;
* ``V.pt``: ``q [B,d] -> V(q) [B]``, the potential energy;
* ``C.pt``: ``q [B,d] -> C(q) [B,d,d]``, the Rayleigh matrix (``D = 1/2 qdot^T C(q) qdot``);
* ``b.pt`` (with measured inputs only): ``q [B,d] -> b(q) [B,n_u,d]``, the input map (``f_P = b(q)^T u``).

Load with ``torch.jit.load(path)``; inputs are float64, ``q`` in the chart's whitened units.
"""

from __future__ import annotations

import copy
from pathlib import Path

import torch
from torch import Tensor, nn

from lagsplat.io.atomic import atomic_write
from lagsplat.models.lagrangian import Lagrangian

__all__ = ["TERMS", "term_modules", "write_torchscript"]

TERMS = {"M": "M.pt", "V": "V.pt", "C": "C.pt", "b": "b.pt"}
"""Term name -> file name in the export folder."""


class _MatrixField(nn.Module):
    """One of the model's ``q [B,d] -> [B,d,d]`` fields, by method name (``mass_matrix``, ``dissipation_matrix``)."""

    def __init__(self, model: Lagrangian, method: str) -> None:
        super().__init__()
        self.model, self.method = model, method

    def forward(self, q: Tensor) -> Tensor:
        return getattr(self.model, self.method)(q)


class _Potential(nn.Module):
    """``V(q)`` with the rest-state terms ``phi(q*)``, ``g(phi(q*))`` and ``grad g(phi(q*))`` precomputed
    (:class:`~lagsplat.models.icnn.ConvexPotential` takes them by autograd at every call, which a trace cannot hold)."""

    def __init__(self, model: Lagrangian) -> None:
        super().__init__()
        pot = model.potential_hat
        self.g, self.phi, self.eps, self.s_V = pot.g, pot.phi, float(pot.eps), model.s_V
        with torch.no_grad():
            y = pot.q_rest.detach()[None]
            y = y if self.phi is None else self.phi(y)
            self.register_buffer("y_rest", y[0].clone())
            self.register_buffer("g_rest", self.g(y)[0].clone())
            self.register_buffer("grad_rest", self.g.gradient(y)[0].clone())

    def forward(self, q: Tensor) -> Tensor:
        y = q if self.phi is None else self.phi(q)
        diff = y - self.y_rest
        return torch.exp(self.s_V) * (self.g(y) - self.g_rest - diff @ self.grad_rest + 0.5 * self.eps * (diff * diff).sum(-1))


class _InputMap(nn.Module):
    """``b(q) [B,n_u,d]`` with rows ``e^{s_V} (a_j - grad g_j(q))`` (:meth:`ConcaveMap.force` is ``b(q)^T u``)."""

    def __init__(self, model: Lagrangian) -> None:
        super().__init__()
        self.act, self.s_V = model.actuation, model.s_V

    def forward(self, q: Tensor) -> Tensor:
        rows = [self.act.a[j] - h.gradient(q) for j, h in enumerate(self.act.heads)]
        return torch.exp(self.s_V) * torch.stack(rows, 1)


def term_modules(model: Lagrangian) -> dict[str, nn.Module]:
    """The eager wrapper of each term of ``model`` (:data:`TERMS`; ``b`` only with inputs), on a float64 copy.

    Raises:
        ValueError: for the decoder-induced inertia (``mass="decoder"``), which is not exported.
    """
    if model.mass_kind == "decoder":
        raise ValueError("mass='decoder' (the decoder-induced inertia) is not exported; export a scalar, constant or learned inertia")
    m = copy.deepcopy(model).double().eval()
    for p in m.parameters():
        p.requires_grad_(False)
    out = {"M": _MatrixField(m, "mass_matrix"), "V": _Potential(m), "C": _MatrixField(m, "dissipation_matrix")}
    if m.n_u:
        out["b"] = _InputMap(m)
    return out


@torch.no_grad()
def write_torchscript(model: Lagrangian, out_dir: str | Path, example: Tensor) -> dict[str, Path]:
    """Trace each term of ``model`` (:func:`term_modules`) at ``example`` and save it under ``out_dir``, atomically.

    Args:
        model: the Stage-2 Lagrangian (any dtype; traced in float64).
        out_dir: the export folder.
        example: ``[B,d]`` states to trace at (chart units), e.g. a few encoded frames.

    Returns:
        Term name -> path written.

    Raises:
        ValueError: for an unsupported model (:func:`term_modules`) or an ``example`` that is not ``[B,d]``.
        RuntimeError: if a traced term does not reproduce the model at other batch sizes.
    """
    if example.dim() != 2 or example.shape[1] != model.d:
        raise ValueError(f"example states must be [B,{model.d}], got {tuple(example.shape)}")
    x = example.detach().to(torch.float64)
    paths = {}
    for name, mod in term_modules(model).items():
        traced = torch.jit.trace(mod, (x,), check_trace=False)
        for other in (x[:1], torch.cat([x, x.flip(0)])):  # other batch sizes: the trace must not have frozen one
            if not torch.allclose(traced(other), mod(other), rtol=1e-12, atol=1e-12):
                raise RuntimeError(f"the traced {name}(q) differs from the model at a batch of {len(other)} states")
        paths[name] = Path(out_dir) / TERMS[name]
        with atomic_write(paths[name]) as tmp:
            torch.jit.save(traced, str(tmp))
    return paths
