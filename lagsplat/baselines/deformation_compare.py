"""The conditioned decoder against the deformation-field decoder at equal budget (paper App. B).

Both Stage-1 autoencoders are trained on the same clip with the same
settings and seed (:mod:`lagsplat.models.deformation`); this module scores
them on the frames they were fitted on and reads their velocity fields:

* reconstruction: mean L1 and SSIM term ``1 - SSIM`` (paper Eq. 5, the SSIM
  window of the Stage-1 settings) over the training frames, each frame
  rendered from its own encoding;
* size: parameters of the decoder alone and with the encoder;
* the Jacobian field: at one state of the clip with a large velocity (the
  training frame of largest ``|qdot|``, ``qdot`` by central differences of
  the encoded trajectory), each primitive's image velocity
  ``|mu_dot_i| = |J_i qdot|`` in px/s, and its *roughness*
  (:func:`roughness`): the median over visible primitives of
  ``| |J_i qdot| - mean_{j in N_k(i)} |J_j qdot| |`` with ``N_k(i)`` the ``k``
  nearest visible primitives by rendered position. An affine field (the
  conditioned decoder's constant ``J_i``, a rigid motion) gives about 0 on a
  smooth object; the paper reads 1.4 px/s for ours against 6.9 for the
  deformation field.

A primitive is *visible* when its compositing weights (the rasteriser's
``T_i a_i``) summed over the image reach ``min_coverage`` pixels. The same
numbers are also read on two parts of the image, from the clip alone
(:func:`lagsplat.motion.motion_masks` of the training frames, 1 px margin):
the visible primitives rendered on *moving* pixels (the object: median speed
and roughness among themselves) and on *static* pixels (the background:
median speed, which a decoder that sets the background in motion raises).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch
from torch import Tensor

from lagsplat.models.autoencoder import AutoEncoder, frames_to_tensor
from lagsplat.train.losses import ssim

__all__ = ["DeformationCompareConfig", "param_counts", "reconstruction_terms", "fast_frame", "velocity_field", "roughness", "compare_decoder"]


@dataclass
class DeformationCompareConfig:
    """Settings of ``python -m lagsplat deformation`` (``conf/config.yaml``, group ``deformation``).

    Attributes:
        table: the table's name: ``results/tables/<table>.tex``, ``.csv`` and ``.json``.
        k_neighbours: neighbours of the roughness (paper App. B: 6).
        min_coverage: a primitive is visible when its compositing weights sum to at least this many pixels.
        forces: the force comparison against the rigid-body truth (:mod:`lagsplat.baselines.deformation_forces`):
            ``auto`` where the clip has one (the synthetic pendulums), ``on``, ``off``.
        batch: frames rendered at once.
    """

    table: str = "deformation"
    k_neighbours: int = 6
    min_coverage: float = 0.5
    forces: Literal["auto", "on", "off"] = "auto"
    batch: int = 32


def param_counts(ae: AutoEncoder) -> dict[str, int]:
    """Parameters of the decoder, the encoder and both: ``{"decoder", "encoder", "total"}``."""
    n = lambda m: int(sum(p.numel() for p in m.parameters()))  # noqa: E731
    dec, enc = n(ae.decoder), n(ae.encoder)
    return {"decoder": dec, "encoder": enc, "total": dec + enc}


@torch.no_grad()
def reconstruction_terms(ae: AutoEncoder, frames: np.ndarray, ssim_window: int = 7, batch: int = 32) -> dict[str, float]:
    """Mean L1 and SSIM term ``1 - SSIM`` of the autoencoder on ``frames`` (uint8 ``[T,H,W,3]``), paper Eq. 5.

    Each batch's terms are weighted by its size, so the result is the mean over frames.

    Raises:
        ValueError: on an empty ``frames``.
    """
    if len(frames) == 0:
        raise ValueError("no frames to score")
    l1 = s = 0.0
    for i in range(0, len(frames), batch):
        x = frames_to_tensor(frames[i : i + batch])
        pred = ae.decode(ae.encode(x))
        l1 += float((pred - x).abs().mean()) * len(x)
        s += float(1.0 - ssim(pred, x, ssim_window)) * len(x)
    return {"l1": l1 / len(frames), "ssim_term": s / len(frames)}


def fast_frame(q: np.ndarray, t: np.ndarray, train_idx: np.ndarray) -> tuple[int, np.ndarray]:
    """The training frame of largest ``|qdot|`` and its ``qdot [d]`` (units of ``q`` per second).

    ``qdot`` by central differences over consecutive training frames (frames
    whose both neighbours are training frames; the ends of a segment are skipped).

    Raises:
        ValueError: if no training frame has two training neighbours.
    """
    idx = np.asarray(sorted(train_idx))
    inner = [i for k, i in enumerate(idx[1:-1], 1) if idx[k - 1] == i - 1 and idx[k + 1] == i + 1]
    if not inner:
        raise ValueError("no training frame with two consecutive neighbours: cannot difference the trajectory")
    qd = np.stack([(q[i + 1] - q[i - 1]) / (t[i + 1] - t[i - 1]) for i in inner])
    k = int(np.argmax(np.linalg.norm(qd, axis=1)))
    return int(inner[k]), qd[k]


@torch.no_grad()
def velocity_field(ae: AutoEncoder, z: Tensor, zdot: Tensor) -> dict[str, Tensor]:
    """Each primitive's rendered position, image velocity and coverage at one state (paper App. B).

    Args:
        ae: a Stage-1 autoencoder (either decoder family).
        z: ``[d]`` raw latent; zdot: ``[d]`` its time derivative (per second).

    Returns:
        ``pos [K,2]`` px, ``velocity [K,2]`` px/s (``J_i(z) zdot``; the constant ``J_i`` of the
        conditioned decoder), ``speed [K]`` px/s, ``coverage [K]`` (compositing weight summed over the
        image, pixels) and ``image [3,H,W]`` (the render).
    """
    dec, H, W = ae.decoder, ae.height, ae.width
    zz = z.reshape(1, -1).float()
    means, _, _ = dec.condition(zz)
    pos = means[0] * means.new_tensor([float(W), float(H)])
    J = dec.pixel_jacobians(zz, H, W) if dec.kind == "deformation" else dec.pixel_geometry(H, W)[0]
    vel = torch.einsum("kid,d->ki", J, zdot.float())
    image, cover = dec.render(zz, H, W, extra=torch.eye(dec.K))
    return {"pos": pos, "velocity": vel, "speed": vel.norm(dim=1), "coverage": cover[0].sum((1, 2)), "image": image[0]}


def roughness(pos: np.ndarray, speed: np.ndarray, k: int = 6) -> np.ndarray:
    """Per-primitive roughness of a speed field: ``| s_i - mean_{j in N_k(i)} s_j |`` (paper App. B).

    Args:
        pos: ``[N,2]`` rendered positions (px).
        speed: ``[N]`` speeds ``|J_i qdot|`` (px/s).
        k: neighbours (the primitive itself excluded; fewer when ``N <= k``).

    Returns:
        ``[N]`` px/s (the caller takes the median).

    Raises:
        ValueError: with fewer than two primitives or mismatched shapes.
    """
    from scipy.spatial import cKDTree

    pos, speed = np.asarray(pos, float), np.asarray(speed, float)
    if len(pos) < 2 or pos.shape != (len(speed), 2):
        raise ValueError(f"need positions [N,2] and speeds [N] with N >= 2, got {pos.shape} and {speed.shape}")
    kk = min(int(k), len(pos) - 1)
    _, nb = cKDTree(pos).query(pos, kk + 1)
    nb = nb[:, 1:]  # the primitive itself comes first (distance 0)
    return np.abs(speed - speed[nb].mean(1))


def _median(x: np.ndarray) -> float:
    return float(np.median(x)) if len(x) else float("nan")


def _on(mask: np.ndarray | None, pos: np.ndarray) -> np.ndarray:
    """Whether each rendered position ``pos [K,2]`` (px) falls on a ``True`` pixel of ``mask [H,W]`` (all False without one)."""
    if mask is None:
        return np.zeros(len(pos), bool)
    H, W = mask.shape
    ok = (pos[:, 0] >= 0) & (pos[:, 0] < W) & (pos[:, 1] >= 0) & (pos[:, 1] < H)
    x, y = np.clip(pos[:, 0].astype(int), 0, W - 1), np.clip(pos[:, 1].astype(int), 0, H - 1)
    return ok & mask[y, x]


def compare_decoder(ae: AutoEncoder, frames: np.ndarray, train_idx, z: np.ndarray, zdot: np.ndarray, cfg: DeformationCompareConfig,
                    ssim_window: int = 7, moving: np.ndarray | None = None, static: np.ndarray | None = None) -> tuple[dict, dict]:  # fmt: skip
    """The App. B numbers of one decoder: ``(row, field)``.

    Args:
        ae: the Stage-1 autoencoder.
        frames: uint8 ``[T,H,W,3]`` of the clip; train_idx: its training frames.
        z, zdot: ``[d]`` raw latent and its rate (per s) at the compared state.
        cfg: settings; ssim_window: the Stage-1 SSIM window.
        moving, static: ``[H,W]`` bool masks of the object and the background (module docstring), or ``None``.

    Returns:
        ``row``: ``decoder``, ``n_gaussians``, ``l1``, ``ssim_term``, ``params_decoder``, ``params_total``,
        ``n_visible``, ``speed_median_px_s``, ``roughness_median_px_s``, and on the object (``n_object``,
        ``speed_object_px_s``, ``roughness_object_px_s``) and the background (``n_static``, ``speed_static_px_s``),
        medians, NaN where no primitive qualifies; ``field``: :func:`velocity_field`
        as numpy arrays plus ``visible [K]`` (for the figure).
    """
    rec = reconstruction_terms(ae, frames[np.asarray(train_idx)], ssim_window, cfg.batch)
    f = {k: v.numpy() for k, v in velocity_field(ae, torch.as_tensor(z), torch.as_tensor(zdot)).items()}
    vis = f["coverage"] >= cfg.min_coverage
    f["visible"] = vis
    rough = roughness(f["pos"][vis], f["speed"][vis], cfg.k_neighbours) if vis.sum() >= 2 else np.array([np.nan])
    obj, bg = vis & _on(moving, f["pos"]), vis & _on(static, f["pos"])
    rough_obj = roughness(f["pos"][obj], f["speed"][obj], cfg.k_neighbours) if obj.sum() >= 2 else np.array([np.nan])
    p = param_counts(ae)
    row = {
        "decoder": ae.decoder.kind, "n_gaussians": int(ae.decoder.K), "l1": rec["l1"], "ssim_term": rec["ssim_term"],
        "params_decoder": p["decoder"], "params_total": p["total"], "n_visible": int(vis.sum()),
        "speed_median_px_s": float(np.median(f["speed"][vis])) if vis.any() else float("nan"),
        "roughness_median_px_s": float(np.median(rough)),
        "n_object": int(obj.sum()), "speed_object_px_s": _median(f["speed"][obj]), "roughness_object_px_s": float(np.median(rough_obj)),
        "n_static": int(bg.sum()), "speed_static_px_s": _median(f["speed"][bg]),
    }  # fmt: skip
    return row, f
