"""A deformation-field decoder: plain 2-D Gaussians warped by a network of the state (paper App. B).

The alternative to the conditioned decoder of :mod:`lagsplat.models.decoder`
that paper App. B compares at equal budget, in the family of Wu et al.'s
4D Gaussian splatting: each of the ``K`` primitives is an ordinary 2-D
Gaussian (canonical centre ``mu_i``, covariance ``Sigma_i = L_i L_i^T``,
opacity ``alpha_i``, colour ``c_i``) with no latent block and no latent gate,
and one small MLP shared by all primitives moves and scales it with the raw
latent ``z``::

    mu_i(z)    = mu_i + MLP_mu(gamma(mu_i), z)
    Sigma_i(z) = exp(2 MLP_s(gamma(mu_i), z)) Sigma_i

with ``gamma`` Fourier features of the canonical position
(``[mu, sin(2^l pi mu), cos(2^l pi mu)]``, ``l < n_freqs``). ``MLP_mu`` and
``MLP_s`` are two linear heads (2 and 1 outputs) on one trunk of SiLU layers;
both heads start at zero, so training starts from the canonical Gaussians.
The extent factor is a scalar per primitive and state, so the aspect ratio
of a rendered Gaussian is its canonical one and the anisotropy cap of the
Stage-1 loss (:func:`lagsplat.train.losses.anisotropy_penalty`, on the
canonical factor) holds at every state: loss, regularisers, recycling and
splitting are those of :class:`~lagsplat.models.decoder.ConditionedGaussians`,
of which this is a subclass, so that the parameterisation of
``z -> mu_i`` is the only difference.

The Jacobian ``J_i(z) = d mu_i / d z`` depends on the state. It is computed
exactly by propagating tangents through the MLP (forward-mode
differentiation; the tests check it against autograd and finite
differences), so it can be penalised in training
(:meth:`render_motion`, the static-pixel prior) and read at any state
(:meth:`pixel_jacobians`, :meth:`state_kinematics`). The affine chart
kinematics of the conditioned decoder (:meth:`chart_kinematics`, a constant
``J_i``, paper Eq. 9) does not exist here and raises.

Units: positions in normalised image coordinates inside the module (as the
conditioned decoder), pixels where a method says so; ``z`` is the raw latent.
"""

from __future__ import annotations

import math
from dataclasses import replace

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from lagsplat.models.decoder import DIAG_FLOOR, ConditionedGaussians, DecoderGeometry, inverse_softplus
from lagsplat.models.decoder3d import ConditionedGaussians3D
from lagsplat.render.rasterize import Backend

__all__ = ["DeformationGaussians", "DECODERS", "build_decoder"]

_LOG_SCALE_MAX = 4.0  # |MLP_s| clamp: extents scaled by at most e^4 either way


def _silu_grad(x: Tensor) -> Tensor:
    """Derivative of ``silu(x) = x sigmoid(x)``."""
    s = torch.sigmoid(x)
    return s * (1.0 + x * (1.0 - s))


class DeformationGaussians(ConditionedGaussians):
    """Decoder: ``K`` plain 2-D Gaussians moved and scaled by a shared MLP of ``(gamma(mu_i), z)`` (paper App. B).

    Args:
        n_gaussians: number of primitives ``K``.
        d: latent dimension.
        backend: rasteriser backend (:func:`lagsplat.render.rasterize.rasterize`).
        background: RGB behind all primitives, in [0, 1].
        hidden: widths of the MLP trunk's SiLU layers (at least one).
        n_freqs: Fourier octaves of ``gamma`` (0: the position alone).
        backdrop: the static layer's ``(h, w)`` (:class:`~lagsplat.models.decoder.ConditionedGaussians`), or ``None``.

    Raises:
        ValueError: on ``n_gaussians < 1``, ``d < 1``, an empty or non-positive ``hidden`` or ``n_freqs < 0``.
    """

    kind = "deformation"

    def __init__(
        self,
        n_gaussians: int,
        d: int,
        backend: Backend = "auto",
        background: tuple[float, float, float] = (0.0, 0.0, 0.0),
        hidden: tuple[int, ...] = (64, 64),
        n_freqs: int = 4,
        backdrop: tuple[int, int] | None = None,
    ) -> None:
        super().__init__(n_gaussians, d, backend, background, backdrop)
        hidden = tuple(int(h) for h in hidden)
        if not hidden or min(hidden) < 1 or int(n_freqs) < 0:
            raise ValueError(f"need hidden widths >= 1 (at least one layer) and n_freqs >= 0, got {hidden}, {n_freqs}")
        self.hidden, self.n_freqs, self.latent_block = hidden, int(n_freqs), 0
        # no latent block: the spatial Cholesky factor alone, no latent means
        del self.mu_q
        self.register_buffer("mu_q", torch.zeros(self.K, 0), persistent=False)
        self.register_buffer("tril_i", torch.tril_indices(2, 2)[0], persistent=False)
        self.register_buffer("tril_j", torch.tril_indices(2, 2)[1], persistent=False)
        self.L_raw = nn.Parameter(torch.zeros(self.K, 3))
        widths = (2 + 4 * self.n_freqs + self.d, *hidden)
        self.trunk = nn.ModuleList(nn.Linear(a, b) for a, b in zip(widths[:-1], widths[1:]))
        self.head_mu, self.head_s = nn.Linear(hidden[-1], 2), nn.Linear(hidden[-1], 1)
        for head in (self.head_mu, self.head_s):
            nn.init.zeros_(head.weight)
            nn.init.zeros_(head.bias)

    def options(self) -> dict:
        """Constructor keywords beyond ``(K, d, backend, background)``, saved in ``stage1.pt``."""
        return {**super().options(), "hidden": list(self.hidden), "n_freqs": self.n_freqs}

    # ---------------------------------------------------------------- geometry
    def cholesky(self) -> Tensor:
        """Canonical spatial Cholesky factor ``L_i``, ``[K,2,2]``."""
        diag = self.tril_i == self.tril_j
        vals = torch.where(diag, F.softplus(self.L_raw) + DIAG_FLOOR, self.L_raw)
        L = vals.new_zeros(self.K, 2, 2)
        L[:, self.tril_i, self.tril_j] = vals
        return L

    def geometry(self) -> DecoderGeometry:
        """Canonical geometry: ``mu_s [K,2]``, ``cov [K,2,2]``, opacities, colours.

        There is no latent block (``mu_q [K,0]``, ``L_qq [K,0,0]``) and no constant Jacobian:
        ``J`` is NaN (the Jacobian depends on the state, :meth:`pixel_jacobians`).
        """
        L = self.cholesky()
        return DecoderGeometry(
            mu_s=self.spatial_mean(self.mu_raw),
            mu_q=self.mu_q,
            L_qq=L.new_zeros(self.K, 0, 0),
            J=L.new_full((self.K, 2, self.d), math.nan),
            cov=L @ L.transpose(-1, -2),
            alpha=torch.sigmoid(self.logit_alpha),
            colors=torch.sigmoid(self.logit_color),
        )

    def features(self, mu_s: Tensor) -> Tensor:
        """Fourier features ``gamma(mu) [K, 2 + 4 n_freqs]`` of canonical positions ``mu_s [K,2]``."""
        out = [mu_s]
        for level in range(self.n_freqs):
            arg = (math.pi * 2.0**level) * mu_s
            out += [torch.sin(arg), torch.cos(arg)]
        return torch.cat(out, -1)

    def field(self, z: Tensor, mu_s: Tensor, jacobian: bool = False) -> tuple[Tensor, Tensor, Tensor | None]:
        """The deformation network at states ``z [B,d]`` for canonical positions ``mu_s [K,2]``.

        Returns:
            ``(offset [B,K,2], log_scale [B,K], J [B,K,2,d] or None)``: the centre offset
            ``MLP_mu`` (normalised units), the extent factor's log ``MLP_s`` (clamped to
            +-4) and, with ``jacobian``, ``d offset / d z`` by forward-mode tangents (exact).
        """
        first = self.trunk[0]
        n_feat = first.in_features - self.d
        W_g, W_z = first.weight[:, :n_feat], first.weight[:, n_feat:]
        pre = (self.features(mu_s) @ W_g.T)[None] + (z @ W_z.T)[:, None] + first.bias  # [B,K,H]
        h = F.silu(pre)
        dh = _silu_grad(pre)[..., None] * W_z[None, None] if jacobian else None  # [B,K,H,d]
        for layer in self.trunk[1:]:
            pre = layer(h)
            if jacobian:
                dh = _silu_grad(pre)[..., None] * torch.einsum("oh,bkhd->bkod", layer.weight, dh)
            h = F.silu(pre)
        offset = self.head_mu(h)
        log_scale = self.head_s(h)[..., 0].clamp(-_LOG_SCALE_MAX, _LOG_SCALE_MAX)
        J = torch.einsum("oh,bkhd->bkod", self.head_mu.weight, dh) if jacobian else None
        return offset, log_scale, J

    def condition(self, z: Tensor, geom: DecoderGeometry | None = None) -> tuple[Tensor, Tensor, DecoderGeometry]:
        """Warp every primitive to the states ``z [B,d]``.

        Returns:
            ``(means [B,K,2], gate [B,K] of ones, geom)``, with ``geom.cov`` the
            state's covariances ``[B,K,2,2]`` (normalised units); there is no latent gate.

        Raises:
            ValueError: if ``z`` is not ``[B,d]``.
        """
        if z.dim() != 2 or z.shape[1] != self.d:
            raise ValueError(f"z must be [B,{self.d}], got {tuple(z.shape)}")
        g = self.geometry() if geom is None else geom
        offset, log_scale, _ = self.field(z, g.mu_s)
        cov = torch.exp(2.0 * log_scale)[..., None, None] * g.cov[None]
        return g.mu_s[None] + offset, torch.ones_like(log_scale), replace(g, cov=cov)

    def pixel_jacobians(self, z: Tensor, height: int, width: int) -> Tensor:
        """``J_i(z) = d mu_i / d z`` in pixels per unit raw latent: ``[K,2,d]`` for ``z [d]`` or ``[1,d]``, ``[B,K,2,d]`` for ``z [B,d]`` (B > 1)."""
        zz = z.reshape(1, -1) if z.dim() == 1 else z
        _, _, J = self.field(zz, self.geometry().mu_s, jacobian=True)
        J = J * J.new_tensor([float(width), float(height)])[None, None, :, None]
        return J[0] if len(zz) == 1 else J

    def state_kinematics(self, q: Tensor, W_inv, mean, height: int, width: int) -> tuple[Tensor, Tensor]:
        """Primitive positions and Jacobians at whitened states ``q [B,d]``, in pixels.

        With ``z = q @ W_inv + mean`` (the chart's de-whitening), ``J_q = J_z W_inv^T``:
        the state-dependent counterpart of the conditioned decoder's :meth:`chart_kinematics`.

        Returns:
            ``(mu [B,K,2] px, J [B,K,2,d] px per unit q)``.
        """
        W_inv = torch.as_tensor(W_inv, dtype=q.dtype)
        z = q @ W_inv + torch.as_tensor(mean, dtype=q.dtype)
        g = self.geometry()
        offset, _, J = self.field(z, g.mu_s, jacobian=True)
        scale = q.new_tensor([float(width), float(height)])
        return (g.mu_s[None] + offset) * scale, torch.einsum("bkid,ld->bkil", J * scale[None, None, :, None], W_inv)

    def pixel_geometry(self, height: int, width: int, geom: DecoderGeometry | None = None) -> tuple[Tensor, Tensor]:
        """Not defined: the Jacobians depend on the state (use :meth:`pixel_jacobians`).

        Raises:
            ValueError: always.
        """
        raise ValueError("the deformation decoder has no constant Jacobian (paper App. B): use pixel_jacobians(z, height, width)")

    def chart_kinematics(self, W_inv, mean, height: int, width: int) -> tuple[Tensor, Tensor]:
        """Not defined: ``q -> mu_i`` is not affine here (use :meth:`state_kinematics`).

        Raises:
            ValueError: always.
        """
        raise ValueError("the deformation decoder's primitives do not move affinely in q (paper App. B): use state_kinematics(q, ...)")

    def render_motion(self, z: Tensor, height: int, width: int, q_std: Tensor) -> tuple[Tensor, Tensor]:
        """Render ``z [B,d]`` with its motion field ``sum_i T_i a_i J_i(z) diag(q_std)`` in pixels.

        As :meth:`ConditionedGaussians.render_motion`, with each state's own Jacobians.

        Returns:
            ``(image [B,3,H,W], motion [B,2d,H,W])``.
        """
        g = self.geometry()
        _, _, J = self.field(z, g.mu_s, jacobian=True)
        J_px = J * J.new_tensor([float(width), float(height)])[None, None, :, None]
        return self.render(z, height, width, geom=g, extra=(J_px * q_std.reshape(1, 1, 1, -1)).reshape(len(z), self.K, -1))

    # ----------------------------------------------------------- initialisation
    def _raw_diagonal(self, sigma_q: Tensor, sigma_xy: float, n: int) -> Tensor:
        """Raw entries ``[n,3]`` of an isotropic spatial factor of std ``sigma_xy`` (``sigma_q`` unused: no latent block)."""
        raw = torch.zeros(n, 3)
        raw[:, (self.tril_i == self.tril_j).cpu()] = float(inverse_softplus(torch.tensor(float(sigma_xy) - DIAG_FLOOR)))
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
    ) -> None:
        """Place the canonical primitives on one frame (as :meth:`ConditionedGaussians.init_from_frame`, without latent means).

        The network starts at zero offset and unit extent; ``z`` and ``sigma_q_floor`` are unused.
        """
        _, H, W = frame.shape
        if prob is None:
            from lagsplat.models.densify import placement_probability

            prob = placement_probability(frame)
        idx = torch.multinomial(prob, self.K, replacement=self.K > H * W, generator=generator)
        self.mu_raw.copy_(self.placement_raw(idx, H, W))
        self.L_raw.copy_(self._raw_diagonal(torch.zeros(0), sigma_xy, self.K))
        self.logit_color.copy_(torch.logit(frame[:, idx // W, idx % W].T.clamp(0.01, 0.99)))
        self.logit_alpha.zero_()

    @torch.no_grad()
    def recycle(self, dead, frame, rendered, z_frame, z_std, sigma_xy: float = 0.05, generator=None, camera=None, depth=None) -> None:
        """Teleport the primitives flagged in ``dead`` to high-error pixels (:meth:`ConditionedGaussians.recycle`, spatial part;
        ``camera`` and ``depth`` as :meth:`ConditionedGaussians.placement_raw`: ``None``)."""
        n_dead = int(dead.sum())
        if n_dead == 0:
            return
        dev = self.mu_raw.device
        frame, rendered = frame.detach().cpu(), rendered.detach().cpu()
        _, H, W = frame.shape
        err = (rendered - frame).abs().mean(0).flatten()
        prob = err if float(err.sum()) > 1e-10 else torch.ones_like(err)
        idx = torch.multinomial(prob, n_dead, replacement=True, generator=generator)
        self.mu_raw[dead] = self.placement_raw(idx, H, W, generator, camera, depth).to(dev)
        self.L_raw[dead] = self._raw_diagonal(torch.zeros(0), sigma_xy, n_dead).to(dev)
        self.logit_color[dead] = torch.logit(frame[:, idx // W, idx % W].T.clamp(0.01, 0.99)).to(dev)
        self.logit_alpha[dead] = -3.0


DECODERS: dict[str, type[ConditionedGaussians]] = {"conditioned": ConditionedGaussians, "deformation": DeformationGaussians,
                                                   "conditioned3d": ConditionedGaussians3D}  # fmt: skip
"""Decoder families by the name ``stage1.decoder`` selects (paper §3.2 and App. B; ``conditioned3d``: §3.2 with
``n = 3``, :mod:`lagsplat.models.decoder3d`)."""


def build_decoder(
    kind: str, n_gaussians: int, d: int, backend: Backend = "auto", background=(0.0, 0.0, 0.0), **options
) -> ConditionedGaussians:
    """A decoder of family ``kind`` (:data:`DECODERS`); ``options`` go to the deformation decoder
    (``hidden``, ``n_freqs``), the 3-D decoder (``camera``, ``depth_range``) and both 2-D decoders (``backdrop``:
    the static layer's ``(h, w)``).

    Raises:
        ValueError: for an unknown ``kind`` (naming the known ones), or a static layer on the 3-D decoder
            (one image behind every view would be wrong in all but one).
    """
    if kind not in DECODERS:
        raise ValueError(f"unknown decoder {kind!r}; expected one of {sorted(DECODERS)} (stage1.decoder)")
    if kind == "conditioned":
        return ConditionedGaussians(n_gaussians, d, backend=backend, background=tuple(background), backdrop=options.get("backdrop"))
    if kind == "conditioned3d":
        if options.get("backdrop") is not None:
            raise ValueError("the 3-D decoder has no static layer (stage1.static_layer applies to the 2-D decoders)")
        options.pop("backdrop", None)
        if "camera" not in options:
            raise ValueError("the 3-D decoder needs the main camera (decoder option 'camera'; a 3-D system's views give it)")
        return ConditionedGaussians3D(n_gaussians, d, backend=backend, background=tuple(background), **options)
    return DeformationGaussians(n_gaussians, d, backend=backend, background=tuple(background), **options)
