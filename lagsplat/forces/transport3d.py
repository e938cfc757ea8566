"""Forces in three dimensions: a pixel of any view, a ray, the first Gaussians it meets, a world-space force.

Paper §4.5 ("Forces in three dimensions") on the 3-D decoder
(:class:`~lagsplat.models.decoder3d.ConditionedGaussians3D`). Each primitive's conditioned mean is affine in the
whitened state, ``mu_i(q) = c_i + J_i q`` with ``J_i [3,d]`` in world units per unit ``q`` (Schur mean, paper
Eq. 2 and 9; :meth:`~lagsplat.models.decoder3d.ConditionedGaussians3D.chart_kinematics`). A click at pixel ``x``
of a camera casts a ray: the state's Gaussians are projected through that camera (EWA), sorted front to back,
and the visible brush of :mod:`lagsplat.forces.transport` weighs each by its compositing share ``T_i a_i`` around ``x``
(with ``min_transmittance`` only the surface the ray meets first). A world-space force ``f [3]`` then enters
the Euler-Lagrange equation as the generalized force ``kappa sum_i w_i J_i^T f`` and the loaded equilibrium is
:meth:`lagsplat.models.lagrangian.Lagrangian.loaded_equilibrium`'s. A push along the viewing direction, which no
image-plane force can express, moves the selected material in depth.

Units: world units (the cameras' extrinsics), whitened ``q``, pixels for the click.
"""

from __future__ import annotations

import torch
from torch import Tensor

from lagsplat.forces.transport import ChartKinematics, Selection, brush_samples, compositing_weights
from lagsplat.render.camera import Camera, depth_order, project_gaussians

__all__ = ["ForceTransport3D"]


class ForceTransport3D(ChartKinematics):
    """World-space kinematics of a trained 3-D decoder in the whitened chart (paper Eq. 9 with ``n = 3``).

    Attributes:
        c: ``[K,3]`` world position of each primitive at ``q = 0``.
        J: ``[K,3,d]`` constant Jacobians, world units per unit ``q``.
        cov: ``[K,3,3]`` world covariances.
        alpha, mu_q, L_qq, W_inv, mean: opacities, latent gates and the chart's de-whitening (as :class:`lagsplat.forces.transport.ForceTransport`).
        min_transmittance: the brush's front-surface threshold ``tau`` (:mod:`lagsplat.forces.transport`).
    """

    def __init__(self, c: Tensor, J: Tensor, cov: Tensor, alpha: Tensor, mu_q: Tensor, L_qq: Tensor, W_inv: Tensor, mean: Tensor,
                 min_transmittance: float = 0.0) -> None:  # fmt: skip
        if not 0.0 <= min_transmittance <= 1.0:
            raise ValueError(f"min_transmittance must be in [0, 1], got {min_transmittance}")
        self.c, self.J, self.cov, self.alpha, self.mu_q, self.L_qq, self.W_inv, self.mean = c, J, cov, alpha, mu_q, L_qq, W_inv, mean
        self.min_transmittance = float(min_transmittance)

    @classmethod
    @torch.no_grad()
    def from_autoencoder(cls, ae, chart, min_transmittance: float = 0.0) -> "ForceTransport3D":
        """Read the world-space Jacobians off a trained 3-D Stage-1 autoencoder and its frozen chart.

        Raises:
            ValueError: if the decoder is not a 3-D one.
        """
        if ae.decoder.n_space != 3:
            raise ValueError("ForceTransport3D needs the 3-D decoder (stage1.decoder=conditioned3d); use lagsplat.forces.transport.ForceTransport")
        g = ae.decoder.geometry()
        c, J = ae.decoder.chart_kinematics(chart.W_inv, chart.mean, ae.height, ae.width)
        W_inv = torch.as_tensor(chart.W_inv, dtype=torch.float32)
        mean = torch.as_tensor(chart.mean, dtype=torch.float32)
        return cls(c, J, g.cov.clone(), g.alpha.clone(), g.mu_q.clone(), g.L_qq.clone(), W_inv, mean, min_transmittance)

    @torch.no_grad()
    def select(self, q: Tensor, camera: Camera, x: Tensor, sigma: float = 1.0) -> Selection:
        """The material under the pixel ``x [2]`` of ``camera`` at the state ``q [1,d]``: compositing weights of the
        projected, depth-sorted Gaussians on a 5 x 5 brush of spacing ``sigma`` px (the visible brush of
        :mod:`lagsplat.forces.transport`), normalised; a zero row when the ray meets nothing.

        Raises:
            ValueError: for a batch of states, or ``sigma <= 0``.
        """
        if q.shape[0] != 1 or not sigma > 0:
            raise ValueError(f"select needs one state q [1,d] and sigma > 0, got {tuple(q.shape)} and {sigma}")
        pts, k = brush_samples(x[None].to(q.dtype), sigma, (camera.height, camera.width))
        w = torch.einsum("s,sk->k", k[0], self.weights(q, camera, pts[0]))
        tot = w.sum()
        return Selection((w / tot if tot > 1e-12 else torch.zeros_like(w))[None])

    def weights(self, q: Tensor, camera: Camera, points: Tensor) -> Tensor:
        """Share of each primitive in the colour ``camera`` renders at the pixel positions ``points [P,2]``, ``[P,K]``
        (in the primitives' own order), at the state ``q [1,d]``: projected (EWA), those behind the camera dropped,
        composited front to back (:func:`lagsplat.forces.transport.compositing_weights`, this transport's ``min_transmittance``)."""
        uv, cov2, depth = project_gaussians(self.means(q), self.cov[None], camera)
        op = self.opacity(q) * (depth > 0).to(q.dtype)
        uv_s, cov_s, op_s, order = depth_order(depth, uv, cov2, op)
        w_sorted = compositing_weights(uv_s[0], cov_s[0], op_s[0], points, self.min_transmittance)
        return torch.zeros_like(w_sorted).scatter_(1, order[0][None].expand_as(w_sorted), w_sorted)

    def pullback(self, sel: Selection, f: Tensor, kappa: float | Tensor = 1.0) -> Tensor:
        """Generalized force ``kappa sum_i w_i J_i^T f [B,d]`` of world forces ``f [B,3]`` (paper Eq. 9)."""
        return kappa * torch.einsum("bk,kid,bi->bd", sel.weights, self.J, f)

    def viewing_direction(self, camera: Camera, x: Tensor) -> Tensor:
        """Unit world direction ``[3]`` of the ray through pixel ``x [2]`` of ``camera`` (away from the camera)."""
        ray = camera.unproject(x[None].to(self.c.dtype), torch.ones(1, dtype=self.c.dtype))[0] - torch.as_tensor(camera.center, dtype=self.c.dtype)
        return ray / ray.norm()
