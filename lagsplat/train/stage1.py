"""Stage 1: joint encoder / conditioned-Gaussian decoder training (paper §3.2, App. C)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal, Mapping

import numpy as np
import torch
from torch import Tensor, nn
from torch.profiler import record_function

from lagsplat.io.clip import TRAIN, Clip
from lagsplat.models.autoencoder import AutoEncoder, frames_to_tensor
from lagsplat.models.decoder import latent_gate
from lagsplat.models.deformation import build_decoder
from lagsplat.models.densify import placement_probability, split_overloaded
from lagsplat.train.anchor import anchor_primitives, departure, object_path, prefit_encoder
from lagsplat.motion import motion_masks
from lagsplat.render.rasterize import Backend
from lagsplat.models.encoder import CpAEEncoder, nonlocal_filter_penalty
from lagsplat.train.config import dataclass_from_mapping
from lagsplat.train.device import resolve_device
from lagsplat.train.plateau import Plateau
from lagsplat.train.losses import reconstruction_loss, static_motion_penalty, temporal_curvature_penalty
from lagsplat.train.progress import Progress
from lagsplat.views import ViewSet, rig_depth, scene_depth_range, static_stereo_depth

__all__ = ["Stage1Config", "train_stage1", "static_pixels"]


@dataclass
class Stage1Config:
    """Stage-1 settings (``conf/config.yaml``, group ``stage1``).

    Attributes mirror the paper's App. C: loss weights 0.08 L1 + 0.02 (1 - SSIM)
    + 0.01 anisotropy with a 7x7 SSIM window, Adam, recycling of primitives
    whose opacity falls below ``alpha_dead``. One optional prior, off by
    default (the paper's loss): ``w_static`` with ``static_margin`` (px;
    :func:`~lagsplat.train.losses.static_motion_penalty` on
    :func:`static_pixels` of the training frames): matter on never-changing
    pixels does not move. ``decoder`` picks the decoder family: ``conditioned``
    (paper §3.2, the method) or ``deformation`` (paper App. B: plain 2-D
    Gaussians warped by an MLP of ``(gamma(mu_i), q)`` of trunk widths
    ``deform_hidden`` and ``deform_freqs`` Fourier octaves,
    :class:`~lagsplat.models.deformation.DeformationGaussians`), trained
    with everything else the same; or ``conditioned3d`` (paper §3.2 with ``n = 3``,
    :class:`~lagsplat.models.decoder3d.ConditionedGaussians3D`), trained on the main view plus the cached
    views of :mod:`lagsplat.views`: each step adds, for ``views_per_step`` training view cameras drawn at
    random, ``w_views`` times the same reconstruction loss on those views of the batch's frames; new
    primitives (initial and recycled, on the main camera or a training view) go on their pixels' rays at the
    plane-sweep stereo depth of that instant (:func:`~lagsplat.views.plane_sweep_depth`), searched in
    ``depth_range`` (world units; ``None``: around where the cameras' axes meet,
    :func:`~lagsplat.views.scene_depth_range`). ``w_depth > 0`` adds, for those views, the relative
    difference between their composited depth and the scene's static stereo depth
    (:func:`static_stereo_depth`), on the pixels whose stereo match is reliable. On the 3-D pendulum
    (64 px, 1500 steps, four training views 40 degrees apart) 0.1 lowered every camera's PSNR by 3-5 dB and
    widened the novel-view gap (4.8 to 5.7 dB), so it stays off by default; nine training views 10 degrees
    apart, without it, bring the gap to 0.4 dB. ``static_layer`` gives a 2-D decoder a static layer
    (:class:`~lagsplat.models.decoder.ConditionedGaussians` ``backdrop``): a learned image behind the
    primitives, started at the per-pixel median of the training frames, with the primitives placed where
    the first frame departs from it and where the frames change (:func:`~lagsplat.models.densify.placement_probability`);
    off, the paper's decoder draws the whole scene with its primitives. The layer makes hiding every
    primitive cheap, and the encoder then learns to do so (its encodings leave every latent gate, the
    image is the layer alone); so with it, ``w_center`` times ``|mean z|^2 + |std z - 1|^2`` over the
    batch keeps the encodings centred with unit spread, and a primitive that no training state shows
    is recycled as a dead one. ``encoder_reference`` has the encoder read each frame's departure from the
    training frames' per-pixel median (the static scene; :meth:`~lagsplat.models.encoder.CpAEEncoder.set_reference`,
    kept with the checkpoint) instead of the frame: on a textured or cluttered scene, or for an object of a
    few pixels, the frame is mostly what never moves, the paper's encoder's encodings then barely change with
    the object, and the decoder, given no usable ``q``, draws the mean image.
    """

    n_gaussians: int = 1024
    steps: int = 3000
    batch: int = 16
    lr_encoder: float = 1e-3
    lr_decoder: float = 3e-3
    w_l1: float = 0.08
    w_ssim: float = 0.02
    w_aniso: float = 0.01
    w_nonlocal: float = 0.0
    w_static: float = 0.0
    static_margin: float = 1.0
    ssim_window: int = 7
    aniso_max_ratio: float = 5.0
    sigma_xy: float = 0.03
    sigma_q_floor: float = 0.5
    alpha_dead: float = 0.02
    recycle_every: int = 250
    recycle_warmup: int = 500
    grad_clip: float = 1.0
    encoder_channels: tuple[int, int, int] = (2, 2, 2)
    encoder_kernel: int = 12
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    backend: Backend = "auto"
    threads: int = 0
    retries: int = 2
    w_motion_init: float = 1.0
    split_share: float = 0.5
    w_temporal: float = 0.0
    plateau_patience: int = 1000
    plateau_tol: float = 0.01
    max_minutes: float = 60.0
    decoder: Literal["conditioned", "deformation", "conditioned3d"] = "conditioned"
    deform_hidden: tuple[int, ...] = (64, 64)
    deform_freqs: int = 4
    w_views: float = 1.0
    views_per_step: int = 1
    depth_range: tuple[float, float] | None = None
    w_depth: float = 0.0
    static_layer: bool = False
    w_center: float = 0.1
    anchor_steps: int = 0
    anchor_share: float = 0.25
    encoder_reference: bool = False

    @classmethod
    def from_mapping(cls, m: Mapping[str, Any]) -> "Stage1Config":
        """Build from a (Hydra) mapping; unknown keys raise ``KeyError``."""
        return dataclass_from_mapping(cls, m, "stage1")


def _reset_adam_rows(opt: torch.optim.Optimizer, params: list[nn.Parameter], mask: Tensor) -> None:
    for p in params:
        st = opt.state.get(p)
        if not st:
            continue
        for key in ("exp_avg", "exp_avg_sq"):
            if key in st and st[key].shape[:1] == mask.shape:
                st[key][mask] = 0.0


def train_stage1(
    clip: Clip,
    cfg: Stage1Config,
    d: int,
    seed: int = 0,
    progress: bool = True,
    device: str = "cpu",
    label: str = "stage1",
    views: ViewSet | None = None,
) -> tuple[AutoEncoder, dict]:
    """Fit encoder and decoder jointly on the clip's training frames.

    Args:
        clip: the ingested clip; only ``clip.train_idx`` frames are used.
        cfg: settings.
        d: latent dimension.
        seed: RNG seed (torch and the batch sampler).
        progress: report progress (:class:`~lagsplat.train.progress.Progress`:
            a tqdm bar on a terminal, a line every ~30 s otherwise).
        device: ``"cpu"`` (the reference), ``"cuda"`` or ``"auto"``
            (:func:`~lagsplat.train.device.resolve_device`). The model is
            initialised on the CPU (the same random draws on every device),
            trained on the device, and returned on the CPU.
        label: what the progress report is headed with (e.g. ``"toy stage1"``).
        views: the clip's cached views (:class:`~lagsplat.views.ViewSet`), for the 3-D decoder.

    Each step's phases are labelled for ``torch.profiler``
    (``stage1.encode``, ``stage1.decode``, ``stage1.loss``,
    ``stage1.backward``, ``stage1.optimizer``, ``stage1.recycle``;
    ``benchmarks/stage1.py`` prints their shares).

    Returns:
        ``(model, history)``, history holding per-step loss terms (every 10 steps)
        and the recycling events.

    Raises:
        ValueError: if the clip has fewer training frames than 2, on a
            device that is not available, or for the 3-D decoder without views
            (or views with another number of frames than the clip).
    """
    dev = resolve_device(device)
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    torch.manual_seed(seed)
    gen = torch.Generator().manual_seed(seed)
    rng = np.random.default_rng(seed)
    frames = clip.images[clip.train_idx]
    if len(frames) < 2:
        raise ValueError("stage 1 needs at least 2 training frames")
    X = frames_to_tensor(frames)
    # centres of triplets of consecutive training frames (positions in X), for the temporal prior
    centres = np.concatenate([np.arange(1, len(seg) - 1) + k for seg, k in _offsets(clip.segments(TRAIN))]) if cfg.w_temporal > 0 else None
    N, _, H, W = X.shape

    static = static_pixels(frames, cfg.static_margin) if cfg.w_static > 0 else None

    enc = CpAEEncoder(d, cfg.encoder_channels, cfg.encoder_kernel)
    if cfg.encoder_reference:
        enc.set_reference(X.median(0).values)
    opts = {"hidden": tuple(cfg.deform_hidden), "n_freqs": cfg.deform_freqs} if cfg.decoder == "deformation" else {}
    V, view_cams, train_views = None, [], []
    if cfg.decoder == "conditioned3d":
        if views is None or len(views.images) != len(clip.t):
            raise ValueError("stage1.decoder=conditioned3d needs the clip's cached views (the views stage), one per frame")
        opts = {"camera": views.cameras[0], "depth_range": tuple(cfg.depth_range) if cfg.depth_range else scene_depth_range(views.cameras)}
        V = torch.from_numpy(np.ascontiguousarray(views.images[clip.train_idx]))  # uint8 [N,M,h,w,3]
        view_cams, train_views = views.cameras[1:], views.train_views
    if cfg.static_layer:
        opts["backdrop"] = (H, W)  # build_decoder refuses it for the 3-D decoder
    dec = build_decoder(cfg.decoder, cfg.n_gaussians, d, backend=cfg.backend, background=cfg.background, **opts)
    backdrop = None
    if cfg.static_layer:
        backdrop = X.median(0).values  # [3,H,W]: what the frames show most of the time
        dec.set_backdrop(backdrop)
    def encode_all() -> Tensor:
        """``[N,d]`` encodings of all training frames, in batches of 256 (call under ``no_grad``)."""
        return torch.cat([enc(X[i : i + 256]) for i in range(0, N, 256)])

    anchored = cfg.anchor_steps > 0 and cfg.decoder == "conditioned"
    D = departure(X) if anchored else None  # each frame's departure from the median, read once for the path and the placement
    if anchored:  # the encoder first follows the object's path (lagsplat.train.anchor)
        prefit_encoder(enc, X, object_path(X, D), cfg.anchor_steps, cfg.lr_encoder, cfg.batch, rng)
    with torch.no_grad():
        z0 = encode_all()
    motion_std = X.std(0).mean(0) if cfg.w_motion_init > 0 else None  # [H,W] temporal std of the training frames
    sxy = dec.spatial_sigma(cfg.sigma_xy)  # the initial spatial extent in the decoder's units

    def stereo_depth(j: int, c: int) -> Tensor:
        """3-D: the plane-sweep depth ``[h*w]`` of camera ``c`` of the training rig (main camera, then the training
        views) at training frame ``j``, where new primitives on that camera's pixels go."""
        return torch.from_numpy(rig_depth(frames, views, clip.train_idx, j, c, dec.depth_range)).flatten()

    depth_target = static_stereo_depth(frames, views, clip.train_idx, dec.depth_range) if V is not None and cfg.w_depth > 0 else None

    dec.init_from_frame(X[0], z0, sxy, cfg.sigma_q_floor, generator=gen, prob=placement_probability(X[0], motion_std, cfg.w_motion_init, backdrop),
                        **({"depth": stereo_depth(0, 0)} if V is not None else {}))  # fmt: skip
    if anchored:
        anchor_primitives(dec, X, z0, cfg.anchor_share, sxy, gen, D=D)
    model = AutoEncoder(enc, dec, H, W).to(dev)
    X = X.to(dev)
    static = None if static is None else static.to(dev)

    dec_params = list(dec.parameters())
    opt = torch.optim.Adam(  # fused: one kernel for all parameters (the per-tensor loop costs more on the CPU)
        [{"params": enc.parameters(), "lr": cfg.lr_encoder}, {"params": dec_params, "lr": cfg.lr_decoder}], fused=True
    )
    history: dict[str, list] = {"step": [], "loss": [], "l1": [], "ssim": [], "recycled": []}
    bar = Progress(cfg.steps, label, enabled=progress)
    order = rng.permutation(N)
    pos = 0
    ema = None
    plateau = Plateau(cfg.plateau_patience, cfg.plateau_tol, max_seconds=60.0 * cfg.max_minutes)
    probe = X[torch.as_tensor(np.unique(np.linspace(0, N - 1, min(N, 64)).round().astype(int)))]
    for step in bar:
        if (step + 1) % cfg.recycle_every == 0 and step + 1 >= cfg.recycle_warmup + cfg.recycle_every:
            # converged? asked where a recycling would come, so the last recycled primitives have trained a full period
            with torch.no_grad():
                why = plateau.check(step, ema, enc(probe).detach().cpu().double().numpy())
            if why is not None:
                history["stopped"] = {"step": step, "reason": why}
                break
        if pos + cfg.batch > N:
            order, pos = rng.permutation(N), 0
        idx = order[pos : pos + min(cfg.batch, N)]
        pos += len(idx)
        x = X[idx]
        with record_function("stage1.encode"):
            z = enc(x)
        with record_function("stage1.decode"):
            if static is not None:
                zs = z.detach().std(0).clamp_min(1e-3) if len(idx) > 1 else torch.ones(d, device=dev)
                pred, motion = dec.render_motion(z, H, W, zs)
            else:
                pred = dec(z, H, W)
            view_preds, depth_loss = [], torch.zeros((), device=dev)
            for m in rng.choice(train_views, size=min(cfg.views_per_step, len(train_views)), replace=False) if V is not None else []:
                target = V[torch.as_tensor(idx), int(m)].to(dev).permute(0, 3, 1, 2).float().div_(255.0)
                if depth_target is None:
                    view_preds.append((dec.render(z, target.shape[2], target.shape[3], camera=view_cams[int(m)])[0], target))
                else:
                    img, dep, alpha = dec.render_depth(z, target.shape[2], target.shape[3], camera=view_cams[int(m)])
                    view_preds.append((img, target))
                    D, mask = (t.to(dev) for t in depth_target[1 + list(train_views).index(int(m))])
                    valid = mask[None, None] & (alpha > 0.5)
                    rel = (dep / alpha.clamp_min(1e-6) - D) / D
                    depth_loss = depth_loss + cfg.w_depth * rel.abs()[valid].mean() if valid.any() else depth_loss
        with record_function("stage1.loss"):
            loss, parts = reconstruction_loss(
                pred, x, dec, cfg.w_l1, cfg.w_ssim, cfg.w_aniso, cfg.ssim_window, cfg.aniso_max_ratio
            )
            for pv, target in view_preds:
                lv, _ = reconstruction_loss(pv, target, dec, cfg.w_l1, cfg.w_ssim, 0.0, cfg.ssim_window, cfg.aniso_max_ratio)
                loss = loss + cfg.w_views / len(view_preds) * lv
            if view_preds:
                loss = loss + depth_loss / len(view_preds)
            if cfg.w_nonlocal > 0:
                loss = loss + cfg.w_nonlocal * nonlocal_filter_penalty(enc.large_kernels())
            if static is not None:
                loss = loss + cfg.w_static * static_motion_penalty(motion, static)
            if backdrop is not None and cfg.w_center > 0 and len(idx) > 1:  # the encodings may not flee every primitive's gate
                loss = loss + cfg.w_center * (z.mean(0).pow(2) + (z.std(0) - 1.0).pow(2)).sum()
            if centres is not None and len(centres):
                c = torch.as_tensor(rng.choice(centres, size=max(1, cfg.batch // 2)), device=dev)
                loss = loss + cfg.w_temporal * temporal_curvature_penalty(enc(X[torch.cat([c - 1, c, c + 1])]).reshape(3, len(c), -1), z)
        with record_function("stage1.backward"):
            opt.zero_grad(set_to_none=True)
            loss.backward()
        with record_function("stage1.optimizer"):
            nn.utils.clip_grad_norm_(enc.parameters(), cfg.grad_clip, foreach=True)
            nn.utils.clip_grad_norm_(dec_params, cfg.grad_clip, foreach=True)
            opt.step()
        lv = float(loss.detach())
        ema = lv if ema is None else 0.95 * ema + 0.05 * lv
        if step % 10 == 0:
            history["step"].append(step)
            history["loss"].append(lv)
            history["l1"].append(parts["l1"])
            history["ssim"].append(parts["ssim"])
            bar.update(loss=ema, l1=parts["l1"], ssim=parts["ssim"])
        # Recycling of dead primitives; never in the last period, so that every
        # recycled primitive is trained before the model is saved (fixes the
        # reference's prune-at-last-epoch, the reference code).
        at_period = (step + 1) % cfg.recycle_every == 0
        if step >= cfg.recycle_warmup and at_period and step + cfg.recycle_every < cfg.steps:
            with torch.no_grad(), record_function("stage1.recycle"):
                dead = torch.sigmoid(dec.logit_alpha) < cfg.alpha_dead
                Z = encode_all() if backdrop is not None else None  # every training frame's encoding, encoded once
                if Z is not None:  # the static layer makes hiding every primitive cheap: one that no training state shows is dead too
                    g = dec.geometry()
                    dead |= torch.sigmoid(dec.logit_alpha) * latent_gate(Z, g.mu_q, g.L_qq, g.L_qq_inv).amax(0) < cfg.alpha_dead
                n_dead = int(dead.sum())
                if n_dead:
                    j = int(rng.integers(N))
                    zj = enc(X[j : j + 1])
                    cam, target, extra = None, X[j], {}
                    if V is not None:  # 3-D: the high-error pixels of the main camera or of a training view, at random
                        m = int(rng.integers(len(train_views) + 1)) - 1
                        if m >= 0:
                            cam = view_cams[train_views[m]]
                            target = V[j, train_views[m]].to(dev).permute(2, 0, 1).float().div_(255.0)
                        extra = {"camera": cam, "depth": stereo_depth(j, m + 1)}
                    rendered = dec(zj, target.shape[1], target.shape[2], camera=cam)[0]
                    zs = (encode_all() if Z is None else Z).std(0)
                    n_split = int(round(cfg.split_share * n_dead))
                    to_split = dead & (torch.cumsum(dead.long(), 0) <= n_split)
                    used, split = split_overloaded(dec, to_split, zs, sxy) if n_split else (torch.zeros_like(dead),) * 2
                    dec.recycle(dead & ~used, target, rendered, zj[0], zs, sxy, generator=gen, **extra)
                    _reset_adam_rows(opt, dec.primitive_parameters(), dead | split)
                history["recycled"].append((step, n_dead))
    return model.cpu().eval(), history


def _offsets(segs: list[np.ndarray]) -> list[tuple[np.ndarray, int]]:
    """Each training segment with the position of its first frame among the concatenated training frames."""
    out, k = [], 0
    for seg in segs:
        out.append((seg, k))
        k += len(seg)
    return out


def static_pixels(frames: np.ndarray, margin: float = 1.0) -> Tensor | None:
    """Pixels whose colour never changes in ``frames`` (uint8 ``[T,H,W,3]``), at least ``margin`` px from any that does.

    The ``changing`` rule of :func:`lagsplat.motion.motion_masks`
    (temporal std above 1.5x the noise floor); ``[H,W]`` bool, or ``None``
    when nothing in the frames changes (no motion to separate from).
    """
    try:
        _, static, _ = motion_masks(frames, sigma=max(margin, 1e-6) / 3.0)
    except ValueError:
        return None
    return torch.from_numpy(static)
