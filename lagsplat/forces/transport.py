"""Forces at inference: pull an image-plane force back into the latent dynamics.

Paper §3.4 (Eq. 9) and App. A.1. Each primitive's conditioned mean is affine in
the state, ``mu_i(q) = c_i + J_i q`` (Schur mean, paper Eq. 2), so its Jacobian
``J_i = d mu_i / d q`` is a constant read off the covariance blocks
(``Sigma_sq Sigma_qq^-1``). A force ``f`` (pixels, image axes ``x`` right,
``y`` down) applied around an image point ``x`` enters the Euler-Lagrange
equation as the generalized force

    f_lat = kappa * sum_i w_i J_i^T f,
    w_i ∝ alpha_i g_i(q) exp(-|mu_i(q) - x|^2 / 2 sigma^2),  sum_i w_i = 1,

with ``g_i`` the latent gate (paper Eq. 4), ``sigma`` the brush radius in
pixels, and ``kappa`` the single energy factor the video leaves unidentified
(paper §3.4 "What the kinematics cannot supply is the scale"), calibrated from
one known (force, displacement) pair by :func:`calibrate_kappa`.

Two brushes (``brush=``):

* ``"paper"``: the weights above, verbatim from paper §3.4. They ignore
  occlusion: opaque background primitives behind a thin moving part get the
  same weight as the part itself, diluting its Jacobian.
* ``"visible"`` (default): what the click actually touches in the render,
  ``w_i ∝ sum_s k_sigma(s) T_i(x + s) a_i(x + s)``, the compositing weight of
  primitive ``i`` (its alpha times the transmittance ``T_i`` in front of it,
  the rasteriser's rule of :mod:`lagsplat.render.rule`) summed over
  brush samples ``s`` on a 5 x 5 grid of spacing ``sigma`` weighted by
  ``exp(-|s|^2 / 2 sigma^2)``, samples off the image dropped (primitives
  outside the frame are never seen, so the video leaves their ``J_i`` free).
  On an unoccluded primitive far from others it reduces to the paper's
  weights; on a thin rod in front of a background it selects the rod (paper
  §4.5: "the first Gaussian it meets becomes the point of application").
  With ``min_transmittance`` ``tau > 0`` only the surface the ray meets first
  counts: a sample's weight on primitive ``i`` is dropped where
  ``T_i < tau``, so colour that shows through a not quite opaque part (a
  static background primitive seen through the checkered pendulum's bob, on
  some trainings; ``docs/experiments/code_comment_history.md``) no longer pulls the
  part's Jacobian towards the background's. Default 0: every composited
  primitive (docs/forces.md gives what ``tau = 0.5`` changes).

A :class:`Selection` freezes the weights of the primitives under the click:
the force keeps acting on the same material while the object moves, and its
application point ``sum_i w_i mu_i(q)`` is re-evaluated at the deformed state.

Units: positions and forces in pixels of the training resolution, latent
``q`` in whitened chart units, time in seconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from lagsplat.models.decoder import latent_gate
from lagsplat.models.lagrangian import Lagrangian

__all__ = ["ChartKinematics", "ForceTransport", "Selection", "EditedDynamics", "calibrate_kappa", "compositing_weights", "brush_samples", "BRUSHES"]

#: Brush weightings of :meth:`ForceTransport.select` (module docstring).
BRUSHES = ("visible", "paper")


@dataclass
class Selection:
    """Frozen brush weights over primitives: ``weights [B,K]``, each row summing to 1 (or 0 when empty)."""

    weights: Tensor


def brush_samples(x: Tensor, sigma: float, size: tuple[int, int] | None = None) -> tuple[Tensor, Tensor]:
    """The visible brush's samples around the points ``x [P,2]`` (px): a 5 x 5 grid of spacing ``sigma``,
    ``(points [P,25,2], weights [P,25])`` with weights ``exp(-|s|^2 / 2 sigma^2)``, zero for samples off a
    ``size = (height, width)`` image (only what is on screen can be touched)."""
    g = torch.arange(-2, 3, dtype=x.dtype) * sigma
    offs = torch.stack(torch.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)  # [25,2]
    pts = x[:, None, :] + offs[None]
    k = torch.exp(-0.5 * (offs**2).sum(-1) / sigma**2)[None].expand(len(x), -1)
    if size is not None:
        H, W = size
        k = k * ((pts[..., 0] >= 0) & (pts[..., 0] <= W) & (pts[..., 1] >= 0) & (pts[..., 1] <= H))
    return pts, k


def compositing_weights(mu: Tensor, cov: Tensor, opacity: Tensor, points: Tensor, min_transmittance: float = 0.0) -> Tensor:
    """Share of each primitive in the rendered colour at each point, ``[P,K]``.

    ``T_i(p) a_i(p)`` with ``a_i`` the primitive's alpha at ``p`` and ``T_i``
    the transmittance of the primitives in front of it: the compositing rule
    of :mod:`lagsplat.render.rule` (front to back in index order, same
    dilation, support and alpha cut-offs).

    Args:
        mu: ``[K,2]`` positions (px) at the state of interest, front to back.
        cov: ``[K,2,2]`` footprints, px^2.
        opacity: ``[K]`` rendered opacities ``alpha_i g_i(q)``.
        points: ``[P,2]`` pixel positions.
        min_transmittance: weights of primitives whose transmittance is
            below this are set to 0 (the visible brush's front surface);
            0 keeps them all, so the weights sum to the rendered coverage.
    """
    from lagsplat.render.rule import ALPHA_MAX, ALPHA_MIN, EPS2D, SUPPORT_SIGMA

    cov = cov + EPS2D * torch.eye(2, dtype=cov.dtype)
    sxx, sxy, syy = cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 1]
    det = (sxx * syy - sxy * sxy).clamp_min(1e-12)
    dx = points[:, None, 0] - mu[None, :, 0]
    dy = points[:, None, 1] - mu[None, :, 1]
    d2 = (syy * dx * dx - 2.0 * sxy * dx * dy + sxx * dy * dy) / det
    a = torch.clamp(opacity[None] * torch.exp(-0.5 * d2), max=ALPHA_MAX)
    r2 = torch.clamp(2.0 * torch.log(255.0 * opacity.clamp_min(1e-30)), max=SUPPORT_SIGMA**2)
    a = torch.where((d2 <= r2[None]) & (a >= ALPHA_MIN), a, torch.zeros_like(a))
    log1m = torch.log1p(-a).double()
    trans = torch.exp(torch.cumsum(log1m, 1) - log1m).to(a.dtype)
    w = trans * a
    return w if min_transmittance <= 0 else torch.where(trans >= min_transmittance, w, torch.zeros_like(w))


class ChartKinematics:
    """Affine primitive motion in the whitened chart, ``mu_i(q) = c_i + J_i q`` (Schur mean, paper Eq. 2 and 9), with
    the latent gates of the opacities (paper Eq. 4): the part of the force transport shared by the image-plane
    (:class:`ForceTransport`, ``n = 2``, pixels) and the world-space one (:class:`lagsplat.forces.transport3d.ForceTransport3D`,
    ``n = 3``). Needs ``c [K,n]``, ``J [K,n,d]``, ``alpha [K]``, ``mu_q``, ``L_qq``, ``W_inv``, ``mean``."""

    c: Tensor
    J: Tensor

    @property
    def d(self) -> int:
        """Latent dimension."""
        return int(self.J.shape[2])

    def means(self, q: Tensor) -> Tensor:
        """Primitive positions ``mu_i(q) [B,K,n]`` (pixels in 2-D, world units in 3-D)."""
        return self.c[None] + torch.einsum("kij,bj->bki", self.J, q)

    def opacity(self, q: Tensor) -> Tensor:
        """Rendered opacity ``alpha_i g_i(q) [B,K]`` (paper Eq. 4)."""
        return self.alpha[None] * latent_gate(q @ self.W_inv + self.mean, self.mu_q, self.L_qq)

    def application_point(self, q: Tensor, sel: Selection) -> Tensor:
        """Where the selected material is at state ``q``: ``sum_i w_i mu_i(q) [B,n]``."""
        return torch.einsum("bk,bki->bi", sel.weights, self.means(q))


class ForceTransport(ChartKinematics):
    """Per-primitive kinematics of a trained decoder in the whitened chart (paper Eq. 9).

    Attributes:
        c: ``[K,2]`` pixel position of each primitive at ``q = 0``.
        J: ``[K,2,d]`` constant Jacobians ``d mu_i / d q`` in pixels per unit ``q``.
        alpha: ``[K]`` base opacities.
        mu_q, L_qq: the latent blocks that gate each primitive (raw latent units).
        W_inv, mean: the chart's de-whitening ``z = q @ W_inv + mean``.
        cov: ``[K,2,2]`` spatial covariances in pixels^2 (the rendered footprints).
        brush: ``"visible"`` or ``"paper"`` (see the module docstring).
        min_transmittance: the visible brush's ``tau``: a primitive counts only
            where at least this share of the light reaches it (module
            docstring); 0 (default) counts every composited primitive.
        size: ``(height, width)`` of the rendered image, px: the visible brush
            only samples inside it (primitives off the frame are not seen).

    Build with :meth:`from_autoencoder`. All tensors float32, CPU.
    """

    def __init__(
        self,
        c: Tensor,
        J: Tensor,
        alpha: Tensor,
        mu_q: Tensor,
        L_qq: Tensor,
        W_inv: Tensor,
        mean: Tensor,
        cov: Tensor | None = None,
        brush: str = "visible",
        size: tuple[int, int] | None = None,
        min_transmittance: float = 0.0,
    ) -> None:
        if brush not in BRUSHES:
            raise ValueError(f"unknown brush {brush!r}; expected one of {BRUSHES}")
        if not 0.0 <= min_transmittance <= 1.0:
            raise ValueError(f"min_transmittance must be in [0, 1], got {min_transmittance}")
        self.min_transmittance = float(min_transmittance)
        self.c, self.J, self.alpha, self.mu_q, self.L_qq, self.W_inv, self.mean = c, J, alpha, mu_q, L_qq, W_inv, mean
        if cov is None:  # isotropic 1 px footprints when the decoder's are not given
            cov = torch.eye(2).expand(len(c), 2, 2).clone()
        self.cov, self.brush, self.size = cov, brush, size

    @classmethod
    @torch.no_grad()
    def from_autoencoder(
        cls, ae, chart, brush: str = "visible", min_transmittance: float = 0.0
    ) -> "ForceTransport":
        """Read the constant Jacobians off a trained Stage-1 autoencoder and its frozen chart.

        Args:
            ae: :class:`~lagsplat.models.autoencoder.AutoEncoder` (its ``decoder``, ``height``, ``width``).
            chart: :class:`~lagsplat.chart.Chart` (``W_inv``, ``mean``).
            brush: ``"visible"`` (default) or ``"paper"``.
            min_transmittance: the visible brush's front-surface threshold (class docstring).
        """
        g = ae.decoder.geometry()
        c, J = ae.decoder.chart_kinematics(chart.W_inv, chart.mean, ae.height, ae.width)
        _, cov = ae.decoder.pixel_geometry(ae.height, ae.width, g)
        W_inv = torch.as_tensor(chart.W_inv, dtype=torch.float32)
        mean = torch.as_tensor(chart.mean, dtype=torch.float32)
        return cls(
            c, J, g.alpha.clone(), g.mu_q.clone(), g.L_qq.clone(), W_inv, mean, cov.clone(), brush, (ae.height, ae.width),
            min_transmittance,
        )

    def compositing_weights(self, mu: Tensor, opacity: Tensor, points: Tensor, min_transmittance: float = 0.0) -> Tensor:
        """Share of each primitive in the rendered colour at each point, ``[P,K]``
        (:func:`compositing_weights` with this decoder's footprints ``cov``)."""
        return compositing_weights(mu, self.cov, opacity, points, min_transmittance)

    def _weights(self, mu: Tensor, opacity: Tensor, x: Tensor, sigma: float) -> Tensor:
        """Unnormalised brush weights ``[P,K]`` at points ``x [P,2]`` for one state."""
        if self.brush == "paper":
            return opacity[None] * torch.exp(-0.5 * ((mu[None] - x[:, None]) ** 2).sum(-1) / sigma**2)
        pts, kk = brush_samples(x, sigma, self.size)
        cw = self.compositing_weights(mu, opacity, pts.reshape(-1, 2), self.min_transmittance).reshape(len(x), pts.shape[1], -1)
        return torch.einsum("ps,psk->pk", kk, cw)

    @staticmethod
    def _normalise(w: Tensor) -> Tensor:
        tot = w.sum(-1, keepdim=True)
        return torch.where(tot > 1e-12, w / tot.clamp_min(1e-30), torch.zeros_like(w))

    def select(self, q: Tensor, x: Tensor, sigma: float) -> Selection:
        """Brush weights at the click (state ``q [B,d]``, point ``x [B,2]`` px, radius ``sigma`` px).

        ``"paper"`` brush: ``w_i ∝ alpha_i g_i(q) exp(-|mu_i(q) - x|^2 / 2 sigma^2)``;
        ``"visible"`` brush: the compositing weights around ``x`` (module
        docstring). Normalised to 1. A brush that reaches no primitive (all
        weights below 1e-12) gives a zero row: the force then acts on nothing.

        Raises:
            ValueError: if ``sigma`` is not positive or shapes disagree.
        """
        if not sigma > 0:
            raise ValueError(f"brush radius sigma must be positive (pixels), got {sigma}")
        if q.shape[0] != x.shape[0] or x.shape[-1] != 2:
            raise ValueError(f"need q [B,d] and x [B,2] with the same B, got {tuple(q.shape)} and {tuple(x.shape)}")
        mu, op = self.means(q), self.opacity(q)
        w = torch.cat([self._weights(mu[b], op[b], x[b : b + 1], sigma) for b in range(len(x))])
        return Selection(self._normalise(w))

    @torch.no_grad()
    def brush_jacobian(self, q: Tensor, points: Tensor, sigma: float, chunk: int = 1024) -> Tensor:
        """Jacobian of the brush at many points, ``J_bar(x) = sum_i w_i(x) J_i`` ``[P,2,d]`` px per unit ``q``.

        The weights are those of :meth:`select` (same brush) at the single state
        ``q [1,d]`` (the state-dependent part is computed once for all points), so the
        generalized force of a force ``f`` at ``x`` is ``kappa J_bar(x)^T f``.
        Zero rows where the brush reaches no primitive.

        Args:
            q: ``[1,d]`` state.
            points: ``[P,2]`` brush centres, pixels.
            sigma: brush radius, pixels (> 0).
            chunk: points per batch (memory ``chunk * K`` floats).

        Raises:
            ValueError: if ``sigma`` is not positive.
        """
        if not sigma > 0:
            raise ValueError(f"brush radius sigma must be positive (pixels), got {sigma}")
        mu = self.means(q)[0]
        op = self.opacity(q)[0]
        out = []
        step = chunk if self.brush == "paper" else max(1, chunk // 25)
        for s in range(0, len(points), step):
            w = self._normalise(self._weights(mu, op, points[s : s + step], sigma))
            out.append(torch.einsum("pk,kid->pid", w, self.J))
        return torch.cat(out) if out else self.J.new_zeros(0, 2, self.d)

    def observed_motion(self, sel: Selection, q: Tensor) -> Tensor:
        """How far the selected material moves over the states ``q [T,d]``: rms displacement ``[B]`` px.

        ``sqrt(mean_t |J_bar (q_t - mean_t q)|^2)`` with ``J_bar = sum_i w_i J_i``
        the selection's Jacobian (paper Eq. 9: :meth:`application_point` is affine
        in ``q``). Given the encoded *training* states it says how much motion
        of this material the video showed the decoder. Its ``J_i`` are learned
        from that motion alone, so where it is below about a pixel the video
        barely constrains them and a force there is extrapolated
        (docs/forces.md: the checkered pendulum's counter-arm, seen moving far less
        than the rod, reads its lever arm short).

        Raises:
            ValueError: if ``q`` is not ``[T,d]`` with ``T >= 1``.
        """
        if q.ndim != 2 or q.shape[1] != self.d or len(q) == 0:
            raise ValueError(f"need training states q [T,{self.d}] with T >= 1, got {tuple(q.shape)}")
        Jb = torch.einsum("bk,kid->bid", sel.weights, self.J)  # [B,2,d]
        dq = q - q.mean(0, keepdim=True)
        return torch.einsum("bid,td->bti", Jb, dq).pow(2).sum(-1).mean(-1).sqrt()

    def pullback(self, sel: Selection | list[Selection], f: Tensor | list[Tensor], kappa: float | Tensor = 1.0) -> Tensor:
        """Generalized force ``kappa sum_i w_i J_i^T f`` ``[B,d]`` (paper Eq. 9).

        Several forces at once: pass lists of selections and forces ``[B,2]``;
        their generalized forces add.
        """
        sels = sel if isinstance(sel, list) else [sel]
        fs = f if isinstance(f, list) else [f]
        if len(sels) != len(fs):
            raise ValueError(f"{len(sels)} selections but {len(fs)} forces")
        out = 0.0
        for s, ff in zip(sels, fs):
            out = out + torch.einsum("bk,kid,bi->bd", s.weights, self.J, ff)
        return kappa * out


class EditedDynamics:
    """A trained Lagrangian with inertia, damping and stiffness rescaled at inference (paper §3.4).

    ``T -> a T``, ``D -> b D``, ``V -> c V``: with ``M qddot = F_V + F_D + F_cor + f``
    this gives ``qddot = M^-1 (c F_V + b F_D + f) / a + M^-1 F_cor`` (the Coriolis
    term scales with ``M`` and cancels). ``force_scale`` multiplies ``f_ext``.

    Exposes ``acceleration(q, qdot, f_ext, u=None)`` like :class:`Lagrangian`.

    Raises:
        ValueError: if a factor is not positive.
    """

    def __init__(self, model: Lagrangian, inertia: float = 1.0, damping: float = 1.0, stiffness: float = 1.0) -> None:
        for name, v in (("inertia", inertia), ("damping", damping), ("stiffness", stiffness)):
            if not (v > 0 and math.isfinite(v)):
                raise ValueError(f"{name} factor must be positive, got {v}")
        self.model, self.a, self.b, self.c = model, float(inertia), float(damping), float(stiffness)

    def acceleration(self, q: Tensor, qdot: Tensor, f_ext: Tensor | None = None, u: Tensor | None = None) -> Tensor:
        """``qddot [B,d]`` of the edited system."""
        m = self.model
        F_V = -m.potential_grad(q)
        F_D = -torch.einsum("bij,bj->bi", m.dissipation_matrix(q), qdot)
        f = m.generalized_force(q, f_ext, u)
        M = m.mass_matrix(q)
        solve = lambda r: torch.linalg.solve(M, r.unsqueeze(-1)).squeeze(-1)  # noqa: E731
        acc_free = m.acceleration(q, qdot)  # M^-1 (F_V + F_D + F_cor)
        edited = self.c * F_V + self.b * F_D + (0.0 if f is None else f)
        out = solve(edited) / self.a + acc_free - solve(F_V + F_D)
        return out if m.training else out.detach()


def calibrate_kappa(
    model: Lagrangian,
    transport: ForceTransport,
    sel: Selection,
    f: Tensor,
    displacement_px: float,
    q_rest: Tensor | None = None,
    bracket: tuple[float, float] = (1e-6, 1e6),
    readout=None,
) -> float:
    """The energy factor ``kappa`` from one known (force, displacement) pair (paper §3.4).

    Finds ``kappa`` such that the static displacement of the selected material,
    ``|p(q_eq) - p(q_rest)|`` with ``p`` the application point and ``q_eq`` the
    loaded equilibrium under ``kappa sum_i w_i J_i^T f``, equals the measured
    ``displacement_px``. The displacement grows monotonically with ``kappa``
    for a convex potential; the root is found by bisection in ``log kappa``
    (``scipy.optimize.brentq``).

    Args:
        model: trained Lagrangian.
        transport: its :class:`ForceTransport`.
        sel: selection of the application point (batch 1).
        f: ``[1,2]`` applied force, in the user's units.
        displacement_px: measured static displacement of that point, pixels (> 0).
        q_rest: unloaded state (default: the model's rest state).
        bracket: search interval for ``kappa``.
        readout: optional ``q_eq [1,d] -> displacement (px)`` measuring the
            static displacement another way (e.g. through a known chart of
            the body); default ``|p(q_eq) - p(q_rest)|`` of the selection.

    Returns:
        ``kappa`` (user force units -> pixel-force units of the model).

    Raises:
        ValueError: if the displacement is not positive, or not reachable within ``bracket``.
    """
    from scipy.optimize import brentq

    if not displacement_px > 0:
        raise ValueError(f"the measured displacement must be positive (pixels), got {displacement_px}")
    q0 = model.q_rest.detach()[None] if q_rest is None else q_rest.reshape(1, -1)
    p0 = transport.application_point(q0, sel)
    base = transport.pullback(sel, f)
    if readout is None:
        readout = lambda q_eq: float((transport.application_point(q_eq, sel) - p0).norm())  # noqa: E731

    def gap(log_k: float) -> float:
        return readout(model.loaded_equilibrium(math.exp(log_k) * base, q0=q0)) - displacement_px

    lo, hi = math.log(bracket[0]), math.log(bracket[1])
    g_lo, g_hi = gap(lo), gap(hi)
    if np.sign(g_lo) == np.sign(g_hi):
        raise ValueError(
            f"a displacement of {displacement_px:.3g} px is not reached for kappa in {bracket} "
            f"(displacements {g_lo + displacement_px:.3g} .. {g_hi + displacement_px:.3g} px)"
        )
    return float(math.exp(brentq(gap, lo, hi, xtol=1e-10, rtol=1e-10)))
