"""Where a grab moves the viewer's image and how stiff the loaded system is: the analysis half of :class:`~lagsplat.viewer.session.Session`.

:class:`Mobility` holds the brush's Jacobians and the mobility map (paper §3.4:
``J_bar(x) = sum_i w_i(x) J_i``, pixels per unit ``q``), the automatic drag
stiffness read off them and the model's stiffest mode, and the number of
integrator sub-steps that the loaded, edited system needs. The session mixes it
in; it reads the session's ``transport``, ``sigma``, ``kappa``, ``q_rest``,
``height``, ``width``, ``dt``, ``max_substeps``, ``params`` and the linearised
model at rest (``_M``, ``_C``, ``_H``) and the held selection ``_sel``.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

__all__ = ["Mobility"]


class Mobility:
    """The brush's reach over the image and the stiffness of the loaded system (a mix-in of :class:`~lagsplat.viewer.session.Session`).

    Expects the attributes that :class:`~lagsplat.viewer.session.Session` sets
    up (listed in this module's docstring); the rest-state mobility map is
    cached on the instance.
    """

    def brush_jacobians(self, points: Tensor, q: Tensor | None = None, chunk: int = 1024) -> Tensor:
        """Jacobian of the brush's application point, ``J_bar(x) = sum_i w_i(x) J_i`` ``[P,2,d]``.

        The weights are those of :meth:`~lagsplat.forces.transport.ForceTransport.select`
        (same formula, with the state-dependent part computed once for all points).

        Args:
            points: ``[P,2]`` pixel positions of the brush centre.
            q: ``[1,d]`` state the weights are read at (default: the rest state).
            chunk: points per batch (memory ``chunk * K`` floats).

        Returns:
            Pixels per unit ``q``; zero rows where the brush reaches no primitive.
        """
        q = self.q_rest if q is None else q
        return self.transport.brush_jacobian(q, points, self.sigma, chunk)

    def mobility_map(self, q: Tensor | None = None) -> np.ndarray:
        """``|J_bar(x)|_2`` at every pixel centre, ``[H,W]`` (pixels per unit ``q``; largest singular value).

        Where a grab moves the image most; zero on material the state does not move.
        The rest-state map (``q=None``) is computed once and cached.
        """
        if q is None and getattr(self, "_mobility_rest", None) is not None:
            return self._mobility_rest
        ys, xs = torch.meshgrid(torch.arange(self.height) + 0.5, torch.arange(self.width) + 0.5, indexing="ij")
        pts = torch.stack([xs.reshape(-1), ys.reshape(-1)], 1)
        Jb = self.brush_jacobians(pts, q)
        m = torch.linalg.matrix_norm(Jb, ord=2).reshape(self.height, self.width).numpy()
        if q is None:
            self._mobility_rest = m
        return m

    def most_mobile_point(self) -> tuple[float, float]:
        """The pixel centre ``(x, y)`` with the largest :meth:`mobility_map` value at rest."""
        m = self.mobility_map()
        r, c = np.unravel_index(int(np.argmax(m)), m.shape)
        return float(c) + 0.5, float(r) + 0.5

    def auto_force_scale(self) -> float:
        """``lambda_max(d2V/dq2 (q_rest)) / (kappa max_x |J_bar(x)|^2)``: pixel force per pixel.

        With this drag stiffness, a grab at the most mobile point of the rest
        image is as stiff as the model's stiffest mode, so a held pointer pulls
        that point about half-way (a usable default for any system, whatever
        the unidentified energy scale).
        """
        s_max = float(self.mobility_map().max())
        lam = float(torch.linalg.eigvalsh(self._H).max())
        if s_max <= 1e-9 or lam <= 0:
            return 1.0
        return lam / (self.kappa * s_max**2)

    def _count_substeps(self) -> int:
        """Sub-steps per step so that ``omega_max h <= 0.5`` and ``gamma_max h <= 0.5`` for the loaded, edited system."""
        p = self.params
        K = p["stiffness"] * self._H
        if self._sel is not None:
            Jb = torch.einsum("bk,kid->id", self._sel.weights.double(), self.transport.J.double())
            K = K + self.kappa * p["force_scale"] * Jb.T @ Jb
        Minv = torch.linalg.inv(self._M * p["inertia"])
        omega2 = float(torch.linalg.eigvals(Minv @ K).real.max().clamp_min(0.0))
        gamma = float(torch.linalg.eigvals(Minv @ (p["damping"] * self._C)).real.max().clamp_min(0.0))
        rate = max(math.sqrt(omega2), gamma)
        return int(min(self.max_substeps, max(1, math.ceil(rate * self.dt / 0.5))))

