"""The drag of the interactive viewer as part of the dynamics: the spring to the pointer inside the acceleration.

(paper §3.4, Eq. 9.) :class:`DraggedDynamics` runs on the autograd path of
:class:`~lagsplat.forces.transport.EditedDynamics`; :class:`CompiledDraggedDynamics` on the
compiled kernels of :mod:`lagsplat.dynamics.fast` (the same numbers). Both are
built by :class:`lagsplat.viewer.session.Session` at every step.
"""

from __future__ import annotations

import numpy as np
from torch import Tensor

from lagsplat.forces.transport import EditedDynamics, ForceTransport, Selection

__all__ = ["DraggedDynamics", "CompiledDraggedDynamics"]


class DraggedDynamics:
    """The edited dynamics plus the spring pulling the selected material to the pointer.

    ``acceleration(q, qdot)`` evaluates the spring at ``q`` itself, so the
    integrator sees the drag as part of the system (a position-dependent force).
    """

    def __init__(self, dyn: EditedDynamics, transport: ForceTransport, sel: Selection, target: Tensor, gain: float, kappa: float) -> None:
        self.dyn, self.transport, self.sel, self.target, self.gain, self.kappa = dyn, transport, sel, target, gain, kappa

    def pixel_force(self, q: Tensor) -> Tensor:
        """``f = gain * (target - p(q)) [B,2]`` px."""
        return self.gain * (self.target - self.transport.application_point(q, self.sel))

    def acceleration(self, q: Tensor, qdot: Tensor, f_ext: Tensor | None = None) -> Tensor:
        """``qddot [B,d]`` with the drag's generalized force added to ``f_ext``."""
        f = self.transport.pullback(self.sel, self.pixel_force(q), self.kappa)
        return self.dyn.acceleration(q, qdot, f if f_ext is None else f + f_ext)


class CompiledDraggedDynamics:
    """:class:`~lagsplat.forces.transport.EditedDynamics` plus the drag on the compiled kernels of :mod:`lagsplat.dynamics.fast`.

    For the inertias the kernels support (``"scalar"``, ``"constant"``) there
    is no Coriolis term, so ``qddot = (c M^-1 F_V + b M^-1 F_D + M^-1 f) / a``
    with ``F_V = -dV/dq``, ``F_D = -C(q) qdot`` read off the kernels. The
    application point is affine in the state (Schur means, paper Eq. 2), so
    the drag uses ``p(q) = c_bar + J_bar q`` with ``c_bar = sum_i w_i c_i``
    and ``J_bar = sum_i w_i J_i`` precomputed at the press:
    ``f_lat = kappa J_bar^T gain (target - p(q))``, the same numbers as
    :class:`DraggedDynamics`. States are float64 NumPy ``[B,d]``.
    """

    def __init__(self, fm, a: float, b: float, c: float, drag: tuple | None = None) -> None:
        self.fm, self.a, self.b, self.c, self.drag = fm, a, b, c, drag

    def acceleration(self, q: np.ndarray, qdot: np.ndarray, f_ext=None) -> np.ndarray:
        from lagsplat.dynamics.fast import fast_acceleration, fast_potential_grad

        f = np.zeros_like(q)
        if self.drag is not None:
            c_bar, J_bar, target, gain, kappa = self.drag
            f = kappa * (gain * (target - c_bar - q @ J_bar.T)) @ J_bar
        acc = fast_acceleration(self.fm, q, qdot, f)  # M^-1 (F_V + F_D + f)
        Minv = self.fm.M_inv
        a_V = -fast_potential_grad(self.fm, q) @ Minv.T
        a_f = f @ Minv.T
        return (self.c * a_V + self.b * (acc - a_V - a_f) + a_f) / self.a
