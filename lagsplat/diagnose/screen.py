"""The decoder's primitives as the main camera sees them, for the image localisation of the gap diagnosis.

:class:`ScreenKinematics` gives, at a chart state, the primitives' pixel positions, their compositing weights
at pixel centres and their pixel motion per unit of ``q``: for the 2-D decoder from its own pixel kinematics
(:class:`lagsplat.forces.transport.ForceTransport`, constant Jacobians ``J_i``, paper Eq. 9), for the 3-D decoder by
projecting its world-space primitives through the main camera (EWA, depth-sorted front to back,
:mod:`lagsplat.render.camera`), the way :meth:`lagsplat.models.decoder3d.ConditionedGaussians3D.render`
draws them.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from lagsplat.forces.transport import ForceTransport
from lagsplat.forces.transport3d import ForceTransport3D
from lagsplat.render.camera import project_points

__all__ = ["ScreenKinematics"]


class ScreenKinematics:
    """Pixel-space view of a decoder's primitives over its chart (module docstring).

    Args:
        transport: a :class:`~lagsplat.forces.transport.ForceTransport` (2-D decoder: pixel kinematics) or a
            :class:`~lagsplat.forces.transport3d.ForceTransport3D` (3-D decoder: world kinematics).
        camera: the main camera at the working resolution (3-D only).

    Raises:
        ValueError: for a 3-D transport without a camera.
    """

    def __init__(self, transport, camera=None) -> None:
        self.tr, self.camera = transport, camera
        self.three_d = isinstance(transport, ForceTransport3D)
        if self.three_d and camera is None:
            raise ValueError("a 3-D decoder's primitives need the main camera to be seen in pixels")
        self.K = int(self.tr.c.shape[0])

    @classmethod
    def from_autoencoder(cls, ae, chart) -> "ScreenKinematics":
        """Of a trained Stage-1 autoencoder (2-D or 3-D decoder) and its frozen chart."""
        if int(ae.decoder.n_space) == 3:
            return cls(ForceTransport3D.from_autoencoder(ae, chart), ae.decoder.camera.resized(int(ae.width), int(ae.height)))
        return cls(ForceTransport.from_autoencoder(ae, chart))

    def opacity(self, q: Tensor) -> Tensor:
        """Opacities ``[1,K]`` at the state ``q [1,d]`` (base opacity times the latent gate)."""
        return self.tr.opacity(q)

    def positions(self, q: Tensor) -> Tensor:
        """Pixel centres ``[K,2]`` of the primitives at the state ``q [1,d]``."""
        if not self.three_d:
            return self.tr.means(q)[0]
        return project_points(self.tr.means(q)[0], self.camera)[0]

    def pixel_jacobians(self, q: Tensor, step: float = 1e-3) -> Tensor:
        """``d uv_i / d q`` ``[K,2,d]`` at ``q [1,d]``: the constant ``J_i`` of the 2-D decoder, central differences of
        ``step`` through the camera for the 3-D one."""
        if not self.three_d:
            return self.tr.J
        cols = []
        for k in range(int(q.shape[1])):
            e = torch.zeros_like(q)
            e[0, k] = step
            cols.append((self.positions(q + e) - self.positions(q - e)) / (2 * step))
        return torch.stack(cols, -1)

    def motion_px(self, q: Tensor) -> np.ndarray:
        """Pixel motion per unit of ``q`` of each primitive, ``[K]`` (Frobenius norm of :meth:`pixel_jacobians`)."""
        return torch.linalg.matrix_norm(self.pixel_jacobians(q)).numpy()

    def weights(self, q: Tensor, points: Tensor) -> Tensor:
        """Share of each primitive in the rendered colour at the pixel positions ``points [P,2]``, ``[P,K]``, at ``q [1,d]``."""
        if not self.three_d:
            return self.tr.compositing_weights(self.tr.means(q)[0], self.tr.opacity(q)[0], points)
        return self.tr.weights(q, self.camera, points)
