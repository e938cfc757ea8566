"""Gaussians in the space--state volume, conditioned on the latent state.

The decoder reads the *raw* latent ``z`` (the encoder's output, ``[B,d]``);
the chart (:mod:`lagsplat.chart`) whitens it to the state ``q = (z - mean) W``
in which the Lagrangian, the metrics and the forces live, and
``Chart.to_raw`` maps back. Below, ``z`` is the raw latent throughout.

Each primitive ``k`` is a Gaussian in ``(2 + d)`` dimensions, spatial block ``s``
(normalised image coordinates: ``x`` in [0, 1] across the width, ``y`` in [0, 1]
down the height, pixel ``j`` centred at ``(j + 0.5) / W``) and latent block
``q``. Rendering a state ``q`` slices every primitive at ``q`` (paper §3.2):

* conditional mean (Schur conditioning, paper Eq. 2)
  ``mu_k(q) = mu_s + Sigma_sq Sigma_qq^-1 (q - mu_q) = mu_s + J_k (q - mu_q)``;
* conditional covariance (paper Eq. 3) ``Sigma_ss - Sigma_sq Sigma_qq^-1 Sigma_qs``,
  independent of ``q``;
* latent-gated opacity (paper Eq. 4)
  ``alpha_k exp(-1/2 (q - mu_q)^T Sigma_qq^-1 (q - mu_q))``.

Parameterisation. The full covariance is ``Sigma = L L^T`` with ``L`` lower
triangular in the coordinate order ``(q, s)``, latent block first::

    L = [[L_qq,   0  ],
         [L_sq,  L_ss]]

Any SPD matrix has such a factor, so this is the paper's family; the order
makes the conditioning exact and cheap: ``Sigma_qq = L_qq L_qq^T``,
``J = Sigma_sq Sigma_qq^-1 = L_sq L_qq^-1`` and the Schur complement is
``L_ss L_ss^T`` (SPD by construction, no matrix inverse, no ridge). The
test-suite checks these closed forms against brute-force conditioning of
``Sigma``. Diagonal entries of ``L`` are ``softplus(raw) + 1e-4``.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from lagsplat.render.rasterize import Backend, rasterize

__all__ = ["ConditionedGaussians", "DecoderGeometry", "inverse_softplus", "latent_gate", "tril_inverse"]

DIAG_FLOOR = 1e-4
"""Floor added to the softplus of each Cholesky diagonal entry (keeps the covariances positive definite)."""
GATE_CLAMP = 20.0
"""Clamp of the gate's squared Mahalanobis distance (:func:`latent_gate`): every gate is at least ``exp(-10)``."""


def inverse_softplus(y: Tensor) -> Tensor:
    """Inverse of ``softplus``: ``x`` with ``softplus(x) = y`` (``y > 0``)."""
    return y + torch.log(-torch.expm1(-y))


def tril_inverse(L: Tensor) -> Tensor:
    """Inverse of lower-triangular matrices ``L [..., d, d]`` with non-zero diagonals.

    ``1 / L`` for ``d = 1`` (the common chart; a generic batched triangular
    solve costs far more there), a triangular solve against the identity
    otherwise.
    """
    if L.shape[-1] == 1:
        return 1.0 / L
    eye = torch.eye(L.shape[-1], dtype=L.dtype, device=L.device).expand_as(L)
    return torch.linalg.solve_triangular(L, eye, upper=False)


def latent_gate(z: Tensor, mu_q: Tensor, L_qq: Tensor, L_qq_inv: Tensor | None = None) -> Tensor:
    """Latent gate ``exp(-1/2 (z - mu_q)^T Sigma_qq^-1 (z - mu_q))`` of every primitive (paper Eq. 4).

    Args:
        z: ``[B,d]`` raw latent states.
        mu_q: ``[K,d]`` latent means.
        L_qq: ``[K,d,d]`` lower-triangular Cholesky factors of ``Sigma_qq``.
        L_qq_inv: their inverses, if already computed (:func:`tril_inverse`).

    Returns:
        ``[B,K]`` in ``[exp(-10), 1]``: the Mahalanobis distance is clamped at
        ``GATE_CLAMP`` so that no gradient vanishes entirely.
    """
    diff = z[:, None, :] - mu_q[None]
    # y = L_qq^-1 (z - mu_q): one inverse per primitive, shared by the batch
    L_inv = tril_inverse(L_qq) if L_qq_inv is None else L_qq_inv
    y = torch.einsum("kij,bkj->bki", L_inv, diff)
    return torch.exp(-0.5 * (y * y).sum(-1).clamp(max=GATE_CLAMP))


@dataclass
class DecoderGeometry:
    """The decoder's state-independent geometry (normalised image units in 2-D, world units in 3-D).

    Attributes:
        mu_s: ``[K,n]`` spatial means (``n = n_space``: normalised image units for 2, world units for 3).
        mu_q: ``[K,d]`` latent means.
        L_qq: ``[K,d,d]`` lower-triangular latent Cholesky block.
        J: ``[K,n,d]`` constant Jacobians ``d mu_k / d q`` (paper Eq. 9).
        cov: ``[K,n,n]`` conditional (rendered) covariances (paper Eq. 3).
        alpha: ``[K]`` base opacities in (0, 1).
        colors: ``[K,3]`` RGB in (0, 1).
        L_qq_inv: ``[K,d,d]`` inverse of ``L_qq`` (:func:`tril_inverse`).
    """

    mu_s: Tensor
    mu_q: Tensor
    L_qq: Tensor
    J: Tensor
    cov: Tensor
    alpha: Tensor
    colors: Tensor
    L_qq_inv: Tensor | None = None


class ConditionedGaussians(nn.Module):
    """Decoder: ``K`` Gaussians in ``(2 + d)``-D, rendered at a latent state ``q``.

    Args:
        n_gaussians: number of primitives ``K``.
        d: latent dimension.
        backend: rasteriser backend (see :func:`lagsplat.render.rasterize.rasterize`).
        background: RGB behind all primitives, in [0, 1] (default black).
        backdrop: ``(h, w)``: a static layer, a learned ``[3,h,w]`` image behind the primitives in place of
            ``background`` (:meth:`set_backdrop`, :meth:`backdrop_image`). It does not depend on ``q``, so it
            adds nothing to ``J``, to ``G_bar`` or to the generalized force (paper Eq. 9): what never moves is
            drawn by it, and the primitives are spent on what moves. ``None`` (the paper's decoder): none.

    The module consumes the *raw* encoder output ``z`` (the unwhitened chart);
    :class:`lagsplat.chart.Chart` maps whitened states back before decoding.
    ``kind`` names the family in ``stage1.pt``; ``latent_block`` is the width of
    the latent block of the Cholesky factor (``d`` here, 0 for the deformation
    decoder of :mod:`lagsplat.models.deformation`, paper App. B).
    """

    kind = "conditioned"
    n_space = 2
    """Spatial dimension ``n`` of the primitives (2: the image plane; 3: world space, :mod:`lagsplat.models.decoder3d`)."""

    def __init__(
        self,
        n_gaussians: int,
        d: int,
        backend: Backend = "auto",
        background: tuple[float, float, float] = (0.0, 0.0, 0.0),
        backdrop: tuple[int, int] | None = None,
    ) -> None:
        super().__init__()
        if n_gaussians < 1 or d < 1:
            raise ValueError(f"need n_gaussians >= 1 and d >= 1, got {n_gaussians}, {d}")
        if backdrop is not None and (len(backdrop) != 2 or min(int(v) for v in backdrop) < 1):
            raise ValueError(f"backdrop must be (height, width) >= 1, got {backdrop}")
        self.K, self.d, self.backend = int(n_gaussians), int(d), backend
        self.latent_block = self.d
        n = self.n_space + d
        self.register_buffer("tril_i", torch.tril_indices(n, n)[0], persistent=False)
        self.register_buffer("tril_j", torch.tril_indices(n, n)[1], persistent=False)
        self.register_buffer("background", torch.tensor(background, dtype=torch.float32))
        self.mu_raw = nn.Parameter(torch.zeros(self.K, self.n_space))
        self.mu_q = nn.Parameter(torch.zeros(self.K, d))
        self.L_raw = nn.Parameter(torch.zeros(self.K, n * (n + 1) // 2))
        self.logit_alpha = nn.Parameter(torch.zeros(self.K))
        self.logit_color = nn.Parameter(torch.zeros(self.K, 3))
        # the static layer's colours as logits, [3,h,w]; grey until set_backdrop
        self.backdrop_raw = None if backdrop is None else nn.Parameter(torch.zeros(3, int(backdrop[0]), int(backdrop[1])))

    def options(self) -> dict:
        """Constructor keywords beyond ``(K, d, backend, background)``, saved in ``stage1.pt``: the static layer's size."""
        return {} if self.backdrop_raw is None else {"backdrop": list(self.backdrop_raw.shape[1:])}

    def primitive_parameters(self) -> list[nn.Parameter]:
        """The per-primitive parameters (first dimension ``K``): what recycling resets rows of."""
        return [p for n, p in self.named_parameters() if "." not in n and n != "backdrop_raw"]

    @torch.no_grad()
    def set_backdrop(self, image: Tensor) -> None:
        """Set the static layer to ``image [3,h,w]`` in [0, 1] (clamped to [0.01, 0.99]), e.g. the median of the training frames.

        Raises:
            ValueError: if the decoder has no static layer, or ``image`` is not ``[3,h,w]`` of its size.
        """
        if self.backdrop_raw is None:
            raise ValueError("this decoder has no static layer (build it with backdrop=(h, w))")
        if tuple(image.shape) != tuple(self.backdrop_raw.shape):
            raise ValueError(f"backdrop image must be {tuple(self.backdrop_raw.shape)}, got {tuple(image.shape)}")
        self.backdrop_raw.copy_(torch.logit(image.clamp(0.01, 0.99)))

    def backdrop_image(self, height: int, width: int) -> Tensor | None:
        """The static layer at ``height x width`` (bilinear when that is not its own size), ``[3,H,W]`` in (0, 1); ``None`` without one."""
        if self.backdrop_raw is None:
            return None
        img = torch.sigmoid(self.backdrop_raw)
        if tuple(img.shape[1:]) != (height, width):
            img = F.interpolate(img[None], size=(height, width), mode="bilinear", align_corners=False)[0]
        return img

    # ---------------------------------------------------------------- geometry
    def spatial_mean(self, raw: Tensor) -> Tensor:
        """Spatial means ``[...,n]`` of raw parameters: ``1.2 sigmoid(raw) - 0.1`` (normalised image units,
        a margin of 0.1 outside the frame)."""
        return 1.2 * torch.sigmoid(raw) - 0.1

    def spatial_raw(self, mu_s: Tensor) -> Tensor:
        """Inverse of :meth:`spatial_mean` (means clamped into its range)."""
        return torch.logit(((mu_s + 0.1) / 1.2).clamp(0.01, 0.99))

    def cholesky(self) -> Tensor:
        """Full lower-triangular factor ``L`` in (q, s) order, ``[K, n+d, n+d]``."""
        n = self.n_space + self.d
        vals = self.L_raw
        diag = self.tril_i == self.tril_j
        vals = torch.where(diag, F.softplus(vals) + DIAG_FLOOR, vals)
        L = vals.new_zeros(self.K, n, n)
        L[:, self.tril_i, self.tril_j] = vals
        return L

    def covariance(self) -> Tensor:
        """Full covariance ``Sigma = L L^T`` in (q, s) order, ``[K, n+d, n+d]``."""
        L = self.cholesky()
        return L @ L.transpose(-1, -2)

    def geometry(self) -> DecoderGeometry:
        """Conditioned geometry of every primitive (see :class:`DecoderGeometry`)."""
        d = self.d
        L = self.cholesky()
        L_qq, L_sq, L_ss = L[:, :d, :d], L[:, d:, :d], L[:, d:, d:]
        L_qq_inv = tril_inverse(L_qq)
        J = L_sq @ L_qq_inv  # J = Sigma_sq Sigma_qq^-1 = L_sq L_qq^-1
        return DecoderGeometry(
            mu_s=self.spatial_mean(self.mu_raw),
            mu_q=self.mu_q,
            L_qq=L_qq,
            J=J,
            cov=L_ss @ L_ss.transpose(-1, -2),
            alpha=torch.sigmoid(self.logit_alpha),
            colors=torch.sigmoid(self.logit_color),
            L_qq_inv=L_qq_inv,
        )

    def condition(self, z: Tensor, geom: DecoderGeometry | None = None) -> tuple[Tensor, Tensor, DecoderGeometry]:
        """Slice every primitive at ``z``.

        Args:
            z: ``[B,d]`` raw latent states.
            geom: precomputed :meth:`geometry` (computed if ``None``).

        Returns:
            ``(means [B,K,2], gate [B,K], geom)``: conditional means in normalised
            image units and the latent gate ``w_z`` in (0, 1]; the rendered
            opacity is ``geom.alpha * gate``.

        Raises:
            ValueError: if ``z`` is not ``[B,d]``.
        """
        if z.dim() != 2 or z.shape[1] != self.d:
            raise ValueError(f"z must be [B,{self.d}], got {tuple(z.shape)}")
        g = self.geometry() if geom is None else geom
        diff = z[:, None, :] - g.mu_q[None]  # [B,K,d]
        means = g.mu_s[None] + torch.einsum("kij,bkj->bki", g.J, diff)
        return means, latent_gate(z, g.mu_q, g.L_qq, g.L_qq_inv), g

    def presence(self, z: Tensor) -> Tensor:
        """Normalised presence weights ``w_hat_i(z)`` (paper Eq. 7), ``[B,K]``, summing to 1."""
        means, gate, g = self.condition(z)
        w = g.alpha[None] * gate
        return w / w.sum(-1, keepdim=True).clamp_min(1e-12)

    def unit_scale(self, height: int, width: int) -> Tensor:
        """``[n_space]`` factors from the decoder's spatial units to the units of its kinematics: pixels of a
        ``height x width`` image here (``[W, H]``); world units, unscaled, in 3-D."""
        return torch.tensor([float(width), float(height)])

    def pixel_geometry(self, height: int, width: int, geom: DecoderGeometry | None = None) -> tuple[Tensor, Tensor]:
        """Jacobians and covariances in pixel units: ``(J_px [K,2,d], cov_px [K,2,2])``."""
        g = self.geometry() if geom is None else geom
        scale = self.unit_scale(height, width).to(g.J)
        return g.J * scale[None, :, None], g.cov * scale[None, :, None] * scale[None, None, :]

    @torch.no_grad()
    def chart_kinematics(self, W_inv, mean, height: int, width: int) -> tuple[Tensor, Tensor]:
        """Affine primitive motion in a whitened chart, in pixels (world units in 3-D, :meth:`unit_scale`): ``mu_i(q) = c_i + J_i q``.

        With ``z = q @ W_inv + mean`` (the chart's de-whitening) the Schur mean
        (paper Eq. 2) ``mu_s + J_z (z - mu_q)`` gives ``J_i = J_z W_inv^T`` and
        ``c_i = mu_s + J_z (mean - mu_q)`` (paper Eq. 9: the constant Jacobians
        that carry forces and the decoder-induced inertia).

        Args:
            W_inv: ``[d,d]``, mean: ``[d]`` (array-like).
            height, width: the resolution whose pixels are the units.

        Returns:
            ``(c [K,n], J [K,n,d])``, float32.
        """
        g = self.geometry()
        scale = self.unit_scale(height, width).to(g.J)
        J_px = g.J * scale[None, :, None]
        W_inv = torch.as_tensor(W_inv, dtype=torch.float32)
        mean = torch.as_tensor(mean, dtype=torch.float32)
        c = g.mu_s * scale + torch.einsum("kij,kj->ki", J_px, mean[None] - g.mu_q)
        return c, torch.einsum("kij,lj->kil", J_px, W_inv)

    # --------------------------------------------------------------- rendering
    def forward(
        self, z: Tensor, height: int, width: int, backend: Backend | None = None, geom: DecoderGeometry | None = None, camera=None
    ) -> Tensor:
        """Render the states ``z [B,d]`` to images ``[B,3,H,W]`` in [0, 1].

        ``geom``: a precomputed :meth:`geometry` (a frozen decoder rendered many
        times, e.g. by the viewer, need not rebuild it per frame). ``camera``: the 3-D decoder's
        (:meth:`screen`); ``None`` here.
        """
        return self.render(z, height, width, backend, geom, camera=camera)[0]

    def screen(self, means: Tensor, gate: Tensor, g: DecoderGeometry, colors: Tensor, height: int, width: int, camera=None):
        """The conditioned primitives as the 2-D rasteriser takes them, front to back: ``(means [B,K,2] px,
        covs px^2, opacities [B,K], colors)``. Here the image plane itself: normalised units scaled to pixels,
        index order (the 3-D decoder projects through a camera and sorts by depth).

        Raises:
            ValueError: if a camera is given (a 2-D decoder has one view).
        """
        if camera is not None:
            raise ValueError("a 2-D decoder renders its one image plane (no camera)")
        scale = means.new_tensor([float(width), float(height)])
        return means * scale, g.cov * scale[None, :, None] * scale[None, None, :], g.alpha[None] * gate, colors

    def render(
        self, z: Tensor, height: int, width: int, backend: Backend | None = None, geom: DecoderGeometry | None = None, extra: Tensor | None = None,
        camera=None,
    ) -> tuple[Tensor, Tensor | None]:  # fmt: skip
        """Render ``z [B,d]`` and, in the same compositing pass, per-primitive channels ``extra``.

        Args:
            z, height, width, backend, geom, camera: as :meth:`forward`.
            extra: ``[K,C]`` (or per state ``[B,K,C]``) values composited like colours over a zero
                background, e.g. each primitive's Jacobian in pixels: the
                result at pixel ``p`` is ``sum_i T_i(p) a_i(p) extra_i``, the
                same compositing weights the visible brush of
                :mod:`lagsplat.forces.transport` uses.

        With a static layer the primitives are composited over zero with one more channel, their
        coverage ``A = 1 - prod_i (1 - a_i)``, and the image is ``rgb + (1 - A) backdrop``; the
        ``extra`` channels keep a zero background (no force acts on the static layer).

        Returns:
            ``(image [B,3,H,W] in [0, 1], extra image [B,C,H,W] or None)``.
        """
        means, gate, g = self.condition(z, geom)
        colors, bg = g.colors, self.background
        backdrop = self.backdrop_image(height, width)
        n_extra = 0 if extra is None else extra.shape[-1]
        if extra is not None:
            colors = colors if extra.dim() == 2 else colors.expand(extra.shape[0], -1, -1)
            colors = torch.cat([colors, extra.to(colors.dtype)], -1)
            bg = torch.cat([bg, bg.new_zeros(n_extra)])
        if backdrop is not None:  # the coverage channel, everything over zero
            colors = torch.cat([colors, colors.new_ones(*colors.shape[:-1], 1)], -1)
            bg = bg.new_zeros(3 + n_extra + 1)
        uv, covs, opacities, colors = self.screen(means, gate, g, colors, height, width, camera)
        img = rasterize(uv, covs, opacities, colors, height, width, background=bg, backend=backend or self.backend)
        rgb = img[:, :3]
        if backdrop is not None:
            rgb = rgb + (1.0 - img[:, -1:]) * backdrop.to(rgb)[None]
        return rgb.clamp(0.0, 1.0), (img[:, 3 : 3 + n_extra] if extra is not None else None)

    def render_motion(self, z: Tensor, height: int, width: int, q_std: Tensor) -> tuple[Tensor, Tensor]:
        """Render ``z [B,d]`` with its motion field, ``sum_i T_i a_i J_i diag(q_std)`` in pixels.

        The field a force applied at each pixel is pulled back through (the
        visible brush of :mod:`lagsplat.forces.transport`, paper Eq. 9), scaled by the
        spread ``q_std [d]`` of the latent; :meth:`render` with ``extra`` the
        per-primitive pixel Jacobians.

        Returns:
            ``(image [B,3,H,W], motion [B,2d,H,W])``.
        """
        J_px, _ = self.pixel_geometry(height, width)
        return self.render(z, height, width, extra=(J_px * q_std.reshape(1, 1, -1)).reshape(self.K, -1))

    # ----------------------------------------------------------- initialisation
    def spatial_sigma(self, sigma_xy: float) -> float:
        """A spatial extent given in normalised image units (``stage1.sigma_xy``) in this decoder's spatial units
        (the same here; world units in 3-D)."""
        return float(sigma_xy)

    def placement_raw(
        self, idx: Tensor, height: int, width: int, generator: torch.Generator | None = None, camera=None, depth: Tensor | None = None
    ) -> Tensor:
        """Raw spatial parameters ``[n, n_space]`` of new primitives at the pixels of flat indices ``idx`` of the
        training view (here the pixel centres themselves; ``generator`` unused; ``camera`` and ``depth`` must be
        ``None``: a 2-D decoder has one view and no depth).

        Raises:
            ValueError: if a camera or a depth is given.
        """
        if camera is not None or depth is not None:
            raise ValueError("a 2-D decoder places primitives in its one image plane (no camera, no depth)")
        return self.spatial_raw(torch.stack([((idx % width).float() + 0.5) / width, ((idx // width).float() + 0.5) / height], -1))

    def _raw_diagonal(self, sigma_q: Tensor, sigma_xy: float, n: int) -> Tensor:
        """Raw Cholesky entries ``[n, m(m+1)/2]`` (``m = n_space + d``) of a diagonal factor (latent stds ``sigma_q [d]``,
        spatial ``sigma_xy``)."""
        m = self.n_space + self.d
        raw = torch.zeros(n, m * (m + 1) // 2)
        is_diag = (self.tril_i == self.tril_j).cpu()
        raw[:, is_diag] = inverse_softplus(torch.cat([sigma_q, torch.full((self.n_space,), sigma_xy)]) - DIAG_FLOOR)
        return raw

    @torch.no_grad()
    def init_from_frame(
        self,
        frame: Tensor,
        z: Tensor,
        sigma_xy: float = 0.05,
        sigma_q_floor: float = 0.5,
        generator: torch.Generator | None = None,
        prob: Tensor | None = None,
        depth: Tensor | None = None,
    ) -> None:
        """Place primitives on one frame, edges favoured (reference "smart init").

        Positions are drawn with probability ``prob`` (default
        :func:`lagsplat.models.densify.placement_probability` of the frame:
        ``0.8 |grad I| / max + 0.2``; with replacement when ``K > H W``), colours are read at those pixels, latent
        means are drawn from ``N(mean z, std z)`` and the latent extent is
        ``max(std z, sigma_q_floor)`` so the gate is open while the encoder is
        still untrained.

        Args:
            frame: ``[3,H,W]`` image in [0, 1].
            z: ``[N,d]`` encodings of the training frames by the initial encoder.
            sigma_xy: spatial standard deviation, in the decoder's spatial units (:meth:`spatial_sigma`).
            sigma_q_floor: lower bound of the latent standard deviation.
            generator: RNG for reproducibility.
            prob: ``[H*W]`` unnormalised placement probability, or ``None``.
            depth: ``[H*W]`` depth of each pixel along the main camera (3-D decoder, :meth:`placement_raw`), or ``None``.
        """
        _, H, W = frame.shape
        if prob is None:
            from lagsplat.models.densify import placement_probability

            prob = placement_probability(frame)
        idx = torch.multinomial(prob, self.K, replacement=self.K > H * W, generator=generator)
        self.mu_raw.copy_(self.placement_raw(idx, H, W, generator, None, None if depth is None else depth[idx]))
        mean, std = z.mean(0), z.std(0).clamp_min(1e-3)
        self.mu_q.copy_(mean + std * torch.randn(self.K, self.d, generator=generator))
        sigma_q = torch.clamp(std.max(), min=sigma_q_floor).repeat(self.d)
        self.L_raw.copy_(self._raw_diagonal(sigma_q, sigma_xy, self.K))
        self.logit_color.copy_(torch.logit(frame[:, idx // W, idx % W].T.clamp(0.01, 0.99)))
        self.logit_alpha.zero_()

    @torch.no_grad()
    def recycle(
        self,
        dead: Tensor,
        frame: Tensor,
        rendered: Tensor,
        z_frame: Tensor,
        z_std: Tensor,
        sigma_xy: float = 0.05,
        generator: torch.Generator | None = None,
        camera=None,
        depth: Tensor | None = None,
    ) -> None:
        """Teleport the primitives flagged in ``dead`` to high-error pixels.

        New positions are drawn with probability proportional to the absolute
        error ``|rendered - frame|`` (channel mean), at the latent ``z_frame`` of
        that frame, with spatial extent ``sigma_xy``, latent extent ``z_std``,
        the pixel colour and opacity ``sigmoid(-3)``.

        Args:
            dead: ``[K]`` bool mask of primitives to move.
            frame, rendered: ``[3,H,W]`` target and current reconstruction.
            z_frame: ``[d]`` raw latent of ``frame``.
            z_std: ``[d]`` per-dimension spread of the training latents.
            camera: the camera ``frame`` was seen by (3-D decoder, :meth:`placement_raw`; ``None``: the main view).
            depth: ``[H*W]`` depth of each pixel of ``frame`` along that camera (3-D decoder), or ``None``.
        """
        n_dead = int(dead.sum())
        if n_dead == 0:
            return
        # drawn on the CPU (the generator's device), written to the parameters' device
        dev = self.mu_raw.device
        frame, rendered, z_frame, z_std = (t.detach().cpu() for t in (frame, rendered, z_frame, z_std))
        _, H, W = frame.shape
        err = (rendered - frame).abs().mean(0).flatten()
        prob = err if float(err.sum()) > 1e-10 else torch.ones_like(err)
        idx = torch.multinomial(prob, n_dead, replacement=True, generator=generator)
        self.mu_raw[dead] = self.placement_raw(idx, H, W, generator, camera, None if depth is None else depth.cpu()[idx]).to(dev)
        self.mu_q[dead] = z_frame.expand(n_dead, -1).to(dev)
        self.L_raw[dead] = self._raw_diagonal(z_std.clamp_min(1e-3), sigma_xy, n_dead).to(dev)
        self.logit_color[dead] = torch.logit(frame[:, idx // W, idx % W].T.clamp(0.01, 0.99)).to(dev)
        self.logit_alpha[dead] = -3.0
