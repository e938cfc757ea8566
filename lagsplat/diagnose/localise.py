"""Where the gap shows in the image, and all four localisations together (:func:`localise`; time in :mod:`lagsplat.diagnose.where_time`, state and latent directions in :mod:`lagsplat.diagnose.where`)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import torch

from lagsplat.diagnose.where import (
    LatentLocalisation,
    StateLocalisation,
    WhereConfig,
    latent_localisation,
    state_localisation,
)
from lagsplat.diagnose.where_time import TimeLocalisation, time_localisation
from lagsplat.io.clip import TRAIN


@dataclass
class ImageLocalisation:
    """Per-pixel excess of the rollout's image error over the AE floor, and its attribution to Gaussians.

    Attributes:
        mean_frame: float ``[H,W,3]`` mean of the frames analysed.
        err_ae: ``[H,W]`` mean squared error (channel mean) of the AE reconstruction.
        err_roll: ``[H,W]`` the same for the rendered rollout states.
        excess: ``[H,W]`` ``err_roll - err_ae``.
        frames: int ``[N]`` chart frames used.
        share: ``[K]`` share of the positive excess attributed to each Gaussian.
        background_share: share left to the background (transmittance past every Gaussian).
        positions: ``[K,2]`` Gaussian centres at the mean encoded state, px.
        motion_px: ``[K]`` ``|J_i|_F``, px per unit whitened ``q``.
        moving: bool ``[K]``: ``motion_px >= moving_fraction x`` its 99th percentile.
        eps_roll, eps_ae: image MSE of the rollouts and of the AE on these frames.
        top_n: Gaussians listed by :meth:`summary`.
        moving_coverage: share of the rendered pixels' colour that moving Gaussians carry
            (same frames and states, every pixel): the share of the excess they would
            get if the excess were spread over the image; their enrichment is
            ``share_moving / moving_coverage``.

    The excess is attributed by the compositing weights at *both* states (encoded
    and simulated, half each): where the simulation draws the object too early or
    too late, the excess at the place the object should be is rendered, in the
    simulation, by whatever is behind it (often static background), and half of
    it is attributed there.
    """

    mean_frame: np.ndarray
    err_ae: np.ndarray
    err_roll: np.ndarray
    excess: np.ndarray
    frames: np.ndarray
    share: np.ndarray
    background_share: float
    positions: np.ndarray
    motion_px: np.ndarray
    moving: np.ndarray
    eps_roll: float
    eps_ae: float
    top_n: int = 10
    moving_coverage: float = float("nan")

    def summary(self) -> dict[str, Any]:
        """JSON-ready numbers (the top Gaussians, moving vs static shares)."""
        top = np.argsort(self.share)[::-1][: self.top_n]
        pos = np.maximum(self.excess, 0.0)
        hot = np.unravel_index(int(np.argmax(pos)), pos.shape) if pos.size else (0, 0)
        return {
            "n_frames": int(len(self.frames)), "eps_rollout": float(self.eps_roll), "eps_ae": float(self.eps_ae),
            "excess_over_ae": float((self.eps_roll - self.eps_ae) / max(self.eps_ae, 1e-300)),
            "share_moving_gaussians": float(self.share[self.moving].sum()), "share_static_gaussians": float(self.share[~self.moving].sum()),
            "share_background": float(self.background_share), "n_moving": int(self.moving.sum()), "n_gaussians": int(len(self.share)),
            "moving_coverage": float(self.moving_coverage),
            "moving_enrichment": float(self.share[self.moving].sum() / self.moving_coverage) if self.moving_coverage > 0 else None,
            "hottest_pixel_xy": [int(hot[1]), int(hot[0])],
            "top_gaussians": [
                {"index": int(i), "share": float(self.share[i]), "position_px": [float(v) for v in self.positions[i]],
                 "motion_px": float(self.motion_px[i]), "moving": bool(self.moving[i])}
                for i in top
            ],
        }  # fmt: skip


def _pick(n: int, k: int) -> np.ndarray:
    if n <= k:
        return np.arange(n)
    return np.unique(np.round(np.linspace(0, n - 1, k)).astype(int))


@torch.no_grad()
def image_localisation(
    images: np.ndarray, ae: Any, chart: Any, frames: np.ndarray, q_sim: np.ndarray, cfg: WhereConfig | None = None
) -> ImageLocalisation:
    """Per-pixel error maps of rendered rollout states against the frames, minus the AE floor, attributed to Gaussians.

    Args:
        images: uint8 ``[T,H,W,3]`` frames of the clip (training resolution).
        ae: the autoencoder (``decoder``, ``height``, ``width``, ``decode(z)``).
        chart: its chart (``q`` the encodings, ``to_raw``, ``W_inv``, ``mean``).
        frames: int ``[N]`` chart frame of each simulated state.
        q_sim: ``[N,d]`` simulated (whitened) states at those frames.
        cfg: settings (``n_image_frames`` states are used, evenly spaced in the list).

    Returns:
        The :class:`ImageLocalisation`.

    Raises:
        ValueError: if no state is given or the frames do not match the decoder's resolution.
    """
    from lagsplat.diagnose.screen import ScreenKinematics
    from lagsplat.models.autoencoder import frames_to_tensor

    cfg = cfg or WhereConfig()
    frames = np.asarray(frames, int)
    if len(frames) == 0:
        raise ValueError("image_localisation: no rollout state to render")
    H, W = int(ae.height), int(ae.width)
    if images.shape[1:3] != (H, W):
        raise ValueError(f"image_localisation: frames are {images.shape[1:3]} but the decoder renders {(H, W)}")
    sel = _pick(len(frames), max(1, int(cfg.n_image_frames)))
    fr, qs = frames[sel], np.asarray(q_sim, np.float64)[sel]
    tr = ScreenKinematics.from_autoencoder(ae, chart)  # the primitives as the main camera sees them (2-D or 3-D decoder)
    K = tr.K
    q_mean = torch.as_tensor(chart.q[fr].mean(0, keepdims=True), dtype=torch.float32)
    motion = tr.motion_px(q_mean)
    moving = motion >= cfg.moving_fraction * float(np.quantile(motion, 0.99)) if float(motion.max()) > 0 else np.zeros(K, bool)
    cover = 0.0
    jj, ii = np.meshgrid(np.arange(W), np.arange(H))
    pts = torch.as_tensor(np.stack([jj.ravel() + 0.5, ii.ravel() + 0.5], 1), dtype=torch.float32)
    acc_ae = np.zeros((H, W))
    acc_sim = np.zeros((H, W))
    acc_exc = np.zeros((H, W))
    attr = np.zeros(K)
    bg = 0.0
    tot_pos = 0.0
    mean_frame = np.zeros((H, W, 3))
    B = 16
    for a in range(0, len(fr), B):
        f_b, q_b = fr[a : a + B], qs[a : a + B]
        x = frames_to_tensor(images[f_b]).double()
        q_enc = torch.as_tensor(chart.q[f_b], dtype=torch.float32)
        q_si = torch.as_tensor(q_b, dtype=torch.float32)
        rec_e = ae.decode(chart.to_raw(q_enc)).double()
        rec_s = ae.decode(chart.to_raw(q_si)).double()
        e_ae = ((rec_e - x) ** 2).mean(1).numpy()  # [b,H,W]
        e_si = ((rec_s - x) ** 2).mean(1).numpy()
        exc = e_si - e_ae
        acc_ae += e_ae.sum(0)
        acc_sim += e_si.sum(0)
        acc_exc += exc.sum(0)
        mean_frame += x.permute(0, 2, 3, 1).numpy().sum(0)
        for b in range(len(f_b)):
            pos = np.maximum(exc[b], 0.0).ravel()
            tot_pos += float(pos.sum())
            for qq in (q_enc[b : b + 1], q_si[b : b + 1]):
                for c0 in range(0, len(pts), int(cfg.pixel_chunk)):
                    w = tr.weights(qq, pts[c0 : c0 + int(cfg.pixel_chunk)]).double().numpy()  # [P,K]
                    pc = pos[c0 : c0 + int(cfg.pixel_chunk)]
                    attr += 0.5 * (w.T @ pc)
                    bg += 0.5 * float(((1.0 - w.sum(1)).clip(0.0, 1.0) * pc).sum())
                    cover += 0.5 * float(w[:, moving].sum())
    n = float(len(fr))
    share = attr / tot_pos if tot_pos > 0 else attr
    positions = tr.positions(q_mean).numpy()
    return ImageLocalisation(
        mean_frame=mean_frame / n, err_ae=acc_ae / n, err_roll=acc_sim / n, excess=acc_exc / n, frames=fr, share=share,
        background_share=bg / tot_pos if tot_pos > 0 else 0.0, positions=positions, motion_px=motion,
        moving=moving, eps_roll=float(acc_sim.mean() / n), eps_ae=float(acc_ae.mean() / n), top_n=int(cfg.top_gaussians),
        moving_coverage=cover / (n * H * W),
    )  # fmt: skip


# ---------------------------------------------------------------------- all four
@dataclass
class Where:
    """The four localisations (any may be ``None`` when it could not be computed, with the reason in ``notes``)."""

    time: TimeLocalisation | None
    state: StateLocalisation | None
    latent: LatentLocalisation | None
    image: ImageLocalisation | None
    notes: list[str] = field(default_factory=list)
    config: dict[str, Any] = field(default_factory=dict)

    def summary(self) -> dict[str, Any]:
        """JSON-ready record for ``report.json``."""
        return {
            "time": None if self.time is None else self.time.summary(),
            "state": None if self.state is None else self.state.summary(),
            "latent": None if self.latent is None else self.latent.summary(),
            "image": None if self.image is None else self.image.summary(),
            "notes": list(self.notes),
            "config": dict(self.config),
        }


def localise(
    model: Any, chart: Any, res: Any, images: np.ndarray | None = None, ae: Any | None = None, cfg: WhereConfig | None = None,
    which: int | None = TRAIN,
) -> Where:
    """Run the four localisations of the module docstring.

    Args:
        model: the fitted model.
        chart: its chart.
        res: the residual of ``model`` on the split ``which`` (as the diagnosis computed it).
        images: uint8 ``[T,H,W,3]`` frames (``None``: no image analysis).
        ae: the autoencoder (``None``: no image analysis).
        cfg: settings.
        which: split analysed (the diagnosis' split).

    Returns:
        The :class:`Where`; an aspect that fails is ``None`` and its reason is in ``notes``.
    """
    cfg = cfg or WhereConfig()
    notes: list[str] = []
    tl = st = lt = im = None
    try:
        tl = time_localisation(model, chart, res, cfg, which)
    except ValueError as exc:
        notes.append(f"time: {exc}")
    try:
        st = state_localisation(res, cfg)
    except ValueError as exc:
        notes.append(f"state: {exc}")
    lt = latent_localisation(res, chart.G_bar, None if tl is None else tl.dq_dir)
    if images is None or ae is None:
        notes.append("image: no frames or autoencoder given")
    elif cfg.n_image_frames <= 0:
        notes.append("image: disabled (n_image_frames = 0)")
    elif tl is None or len(tl.rollouts[0]) == 0:
        notes.append("image: no rollout state to render")
    else:
        try:
            im = image_localisation(images, ae, chart, tl.rollouts[0], tl.rollouts[1], cfg)
        except ValueError as exc:
            notes.append(f"image: {exc}")
    return Where(tl, st, lt, im, notes, asdict(cfg))
