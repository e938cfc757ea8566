"""The conditioned-Gaussian decoder in three dimensions: ``(3 + d)``-D primitives seen through pinhole cameras.

The same family as :class:`lagsplat.models.decoder.ConditionedGaussians` with a spatial block of three
world coordinates (paper §3.2 with ``n = 3``; App. C reconstructs the rocker this way under multi-view
supervision). Slicing a primitive at the state ``z`` is unchanged (Schur conditioning, paper Eq. 2 and 3:
``mu_k(z) = mu_s + J_k (z - mu_q)`` with ``J_k [3,d]`` in world units per latent unit, and a state-independent
``[3,3]`` covariance; the latent gate of Eq. 4). Rendering then projects every conditioned Gaussian through a
camera (:func:`lagsplat.render.camera.project_gaussians`, EWA: ``Sigma_2D = J W Sigma_3D W^T J^T``), sorts
them front to back per state (:func:`~lagsplat.render.camera.depth_order`) and composites them with the 2-D
rasteriser of :mod:`lagsplat.render.rasterize`. A primitive behind the camera's near plane is not drawn.

The decoder holds its *main* camera, the one the clip was filmed with: ``forward(z, H, W)`` renders there, so
the encoder, the chart and everything downstream of Stage 1 read it exactly like the 2-D decoder. Any other
camera is passed to :meth:`ConditionedGaussians3D.render` (cached novel views in Stage 1, novel-view renders).
World units are those of the cameras' extrinsics (metres for a calibrated rig).
"""

from __future__ import annotations

from typing import Mapping, Sequence

import torch
from torch import Tensor

from lagsplat.models.decoder import ConditionedGaussians, DecoderGeometry
from lagsplat.render.camera import NEAR, Camera, depth_order, project_gaussians, project_points
from lagsplat.render.rasterize import Backend

__all__ = ["ConditionedGaussians3D"]


class ConditionedGaussians3D(ConditionedGaussians):
    """Decoder: ``K`` Gaussians in ``(3 + d)``-D world--state space, rendered through pinhole cameras.

    Args:
        n_gaussians, d, backend, background: as :class:`~lagsplat.models.decoder.ConditionedGaussians`.
        camera: the main camera (a :class:`~lagsplat.render.camera.Camera` or its JSON record).
        depth_range: ``(near, far)`` depths along the main camera's axis (world units) between which new
            primitives are placed on the rays of their pixels (initialisation and recycling).

    Raises:
        ValueError: for a depth range that is not ``0 < near <= far``, or a malformed camera record.
    """

    kind = "conditioned3d"
    n_space = 3

    def __init__(
        self,
        n_gaussians: int,
        d: int,
        camera: Camera | Mapping,
        depth_range: Sequence[float] = (1.0, 3.0),
        backend: Backend = "auto",
        background: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> None:
        super().__init__(n_gaussians, d, backend, background)
        self.camera = camera if isinstance(camera, Camera) else Camera.from_dict(dict(camera))
        near, far = (float(v) for v in depth_range)
        if not 0.0 < near <= far:
            raise ValueError(f"depth_range must satisfy 0 < near <= far, got {tuple(depth_range)}")
        self.depth_range = (near, far)

    def options(self) -> dict:
        """Constructor keywords beyond ``(K, d, backend, background)``, saved in ``stage1.pt``."""
        return {"camera": self.camera.to_dict(), "depth_range": list(self.depth_range)}

    # ---------------------------------------------------------------- geometry
    def spatial_mean(self, raw: Tensor) -> Tensor:
        """World means are the raw parameters themselves (world units)."""
        return raw

    def spatial_raw(self, mu_s: Tensor) -> Tensor:
        """Inverse of :meth:`spatial_mean` (the identity)."""
        return mu_s

    def spatial_sigma(self, sigma_xy: float) -> float:
        """``sigma_xy`` (a fraction of the image width) in world units at the middle of the depth range."""
        return float(sigma_xy) * self.camera.width * 0.5 * sum(self.depth_range) / self.camera.fx

    def placement_raw(
        self, idx: Tensor, height: int, width: int, generator: torch.Generator | None = None, camera: Camera | None = None,
        depth: Tensor | None = None,
    ) -> Tensor:  # fmt: skip
        """World points ``[n,3]`` on the rays of ``camera`` (default the main camera) through the pixels ``idx`` (flat,
        of a ``height x width`` image): at ``depth [n]`` (world units along the camera's axis, e.g. a multi-view
        stereo estimate, :func:`lagsplat.views.plane_sweep_depth`) times ``1 -+ 5 %`` drawn at random, or, without
        it, at depths drawn uniformly in ``depth_range`` (the main camera's range; another camera at another
        distance from the scene gets it shifted by the difference of their distances to its mid-range point)."""
        cam = (camera or self.camera).resized(width, height)
        uv = torch.stack([(idx % width).float() + 0.5, (idx // width).float() + 0.5], -1)
        if depth is not None:
            return cam.unproject(uv, depth.float() * (1.0 + 0.05 * (2.0 * torch.rand(len(idx), generator=generator) - 1.0)))
        near, far = self.depth_range
        if camera is not None:  # the same slab of the scene, seen from this camera
            mid = self.camera.unproject(torch.tensor([[self.camera.cx, self.camera.cy]]), torch.tensor([0.5 * (near + far)]))[0]
            shift = float(project_points(mid, camera)[1]) - 0.5 * (near + far)
            near, far = max(near + shift, 1e-3), max(far + shift, 2e-3)
        depth = near + (far - near) * torch.rand(len(idx), generator=generator)
        return cam.unproject(uv, depth)

    def unit_scale(self, height: int, width: int) -> Tensor:
        """World units stay world units (:meth:`ConditionedGaussians.unit_scale`)."""
        return torch.ones(3)

    def pixel_geometry(self, height: int, width: int, geom: DecoderGeometry | None = None) -> tuple[Tensor, Tensor]:
        """Not defined in 3-D: a primitive's image-plane Jacobian depends on the camera and the state.

        Raises:
            NotImplementedError: always; read :meth:`geometry` (world units) or project through a camera.
        """
        raise NotImplementedError("the 3-D decoder has no constant pixel Jacobians; use geometry() (world units) and a camera")

    def render_motion(self, z: Tensor, height: int, width: int, q_std: Tensor) -> tuple[Tensor, Tensor]:
        """Not defined in 3-D (the static-pixel prior, ``stage1.w_static``, is a 2-D prior).

        Raises:
            NotImplementedError: always.
        """
        raise NotImplementedError("the 3-D decoder has no image-plane motion field; set stage1.w_static=0")

    # --------------------------------------------------------------- rendering
    def render_depth(self, z: Tensor, height: int, width: int, camera: Camera | None = None) -> tuple[Tensor, Tensor, Tensor]:
        """Render ``z [B,d]`` through ``camera`` with, in the same compositing pass, the depth along the camera's
        axis (world units) and the accumulated opacity.

        Returns:
            ``(image [B,3,H,W], depth [B,1,H,W], alpha [B,1,H,W])``: ``depth = sum_i T_i a_i z_i`` and
            ``alpha = sum_i T_i a_i``, so ``depth / alpha`` is the expected depth where ``alpha > 0``.
        """
        means, _, _ = self.condition(z)
        _, dep = project_points(means, (camera or self.camera).resized(width, height))
        img, extra = self.render(z, height, width, extra=torch.stack([dep, torch.ones_like(dep)], -1), camera=camera)
        return img, extra[:, :1], extra[:, 1:]

    def screen(self, means: Tensor, gate: Tensor, g: DecoderGeometry, colors: Tensor, height: int, width: int, camera: Camera | None = None):
        """The conditioned primitives seen through ``camera`` (default the main camera, intrinsics scaled to
        ``height x width``, :meth:`Camera.resized`): EWA-projected, those behind the near plane transparent,
        sorted front to back per state (:meth:`ConditionedGaussians.screen`; :meth:`render` renders through it)."""
        cam = (camera or self.camera).resized(width, height)
        uv, cov2, depth = project_gaussians(means, g.cov[None], cam)
        B = means.shape[0]
        opac = g.alpha[None] * gate * (depth > NEAR).to(gate.dtype)
        colors = colors if colors.dim() == 3 else colors.expand(B, -1, -1)
        uv, cov2, opac, colors, _ = depth_order(depth, uv, cov2.expand(B, -1, -1, -1), opac, colors)
        return uv, cov2, opac, colors
