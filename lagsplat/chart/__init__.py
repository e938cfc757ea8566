"""Reading the latent chart (paper §3.2 "Reading the chart"; artifact ``chart.npz``).

Stage 1 closes by freezing two things on the trained autoencoder:

* the whitening ``q = (z - mean) W`` (row vectors), with ``W = V diag(lambda)^-1/2``
  from the eigendecomposition of the covariance of the encoded *training*
  frames (paper App. C), eigenvalues in descending order so ``q[:, 0]`` is the
  principal direction of the raw chart;
* the visibility metric ``G_bar = E_q[J^T J]`` (paper Eq. 6), ``J`` the Jacobian of
  the rendered image (training renderer, training resolution, values in
  [0, 1]) with respect to the whitened ``q``, averaged over encoded training
  frames; and the loss metric ``A = G_bar + rho lambda_max I`` normalised to
  ``trace A = d`` (paper §3.3, "Fitting the dynamics").

It also records the autoencoder floor ``eps_AE``: the MSE between a frame and
its own reconstruction ``decode(encode(frame))``, on training and held-out
frames.

Optionally (``chart.refine_iters > 0``; 0, the paper's chart, by default) each
encoding is first moved to where the decoder draws its frame best
(:func:`refine_latents`). The encoder is amortised and saturates where images are
extreme: it can read the turning points short of where its own decoder draws
them, a flattened peak that Stage 2 then fits as physics. Per frame, the
refinement gives up the encoder's temporal regularity (paper §3.2), and on real
video that can cost more than it buys: it can tear the chart or widen the
held-out gap (the blind suite's and the real clips' measurements are in
``docs/experiments/diagnosis_history.md``).

The package's other modules: :mod:`lagsplat.chart.refine` (that refinement,
:func:`refine_latents`) and :mod:`lagsplat.chart.gate` (the chart-quality gate,
and :func:`~lagsplat.chart.gate.gated_chart`, the chart a run uses).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from lagsplat.io.atomic import atomic_write
from lagsplat.io.clip import HELD_OUT, TRAIN, Clip, segments
from lagsplat.chart.refine import refine_latents
from lagsplat.models.autoencoder import AutoEncoder, frames_to_tensor

__all__ = [
    "Chart",
    "fit_whitening",
    "visibility_metric",
    "loss_metric",
    "chart_continuity",
    "refine_latents",
    "build_chart",
    "save_chart",
    "load_chart",
]

FOLD_WARNING = 5.0


@dataclass
class Chart:
    """The frozen latent chart of one clip.

    Attributes:
        mean: ``[d]`` raw-latent mean of the training encodings.
        W: ``[d,d]`` whitening, ``q = (z - mean) @ W``.
        W_inv: ``[d,d]`` its inverse, ``z = q @ W_inv + mean``.
        q: ``[T,d]`` whitened encodings of every frame of the clip.
        t: ``[T]`` timestamps in seconds.
        split: ``[T]`` 0 = train, 1 = held-out.
        G_bar: ``[d,d]`` visibility metric (per pixel and channel, images in [0, 1]).
        A: ``[d,d]`` loss metric, trace ``d``.
        ae_mse: ``[T]`` per-frame reconstruction MSE.
        ae_floor_train, ae_floor_held_out: mean of ``ae_mse`` over each split.
        height, width: resolution of the images the numbers refer to.
        meta: provenance (sample count, rho, ...).
        episode: ``[T]`` recording index of each frame (multi-clip systems).
        u: ``[T,n_u]`` measured actuation per frame (copied from the clip; ``n_u`` may be 0).
    """

    mean: np.ndarray
    W: np.ndarray
    W_inv: np.ndarray
    q: np.ndarray
    t: np.ndarray
    split: np.ndarray
    G_bar: np.ndarray
    A: np.ndarray
    ae_mse: np.ndarray
    ae_floor_train: float
    ae_floor_held_out: float
    height: int
    width: int
    meta: dict[str, Any] = field(default_factory=dict)
    episode: np.ndarray | None = None
    u: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.episode is None:
            self.episode = np.zeros(len(self.t), np.int16)
        if self.u is None:
            self.u = np.zeros((len(self.t), 0), np.float32)

    @property
    def n_u(self) -> int:
        """Number of actuation channels."""
        return int(self.u.shape[1])

    def segments(self, which: int) -> list[np.ndarray]:
        """Contiguous runs of frames with split ``which`` inside one episode."""
        return segments(self.split, which, self.episode)

    @property
    def d(self) -> int:
        """Latent dimension."""
        return int(self.W.shape[0])

    def to_raw(self, q: Tensor) -> Tensor:
        """Whitened ``q [...,d]`` -> raw decoder input ``z [...,d]``."""
        return q @ torch.as_tensor(self.W_inv, dtype=q.dtype) + torch.as_tensor(self.mean, dtype=q.dtype)

    def to_whitened(self, z: Tensor) -> Tensor:
        """Raw ``z [...,d]`` -> whitened ``q [...,d]``."""
        return (z - torch.as_tensor(self.mean, dtype=z.dtype)) @ torch.as_tensor(self.W, dtype=z.dtype)


def fit_whitening(z: np.ndarray, eps: float = 1e-6) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """PCA whitening of raw latents (paper App. C), in float64.

    Args:
        z: ``[N,d]`` raw encodings of the training frames.
        eps: ridge added to the covariance and eigenvalue floor.

    Returns:
        ``(mean [d], W [d,d], W_inv [d,d])`` with ``(z - mean) @ W`` of identity
        covariance and columns ordered by decreasing variance.

    Raises:
        ValueError: if fewer than ``d + 1`` samples are given.
    """
    z = np.asarray(z, np.float64)
    if z.ndim != 2 or len(z) <= z.shape[1]:
        raise ValueError(f"whitening needs [N,d] with N > d, got {z.shape}")
    mean = z.mean(0)
    cov = np.cov(z, rowvar=False).reshape(z.shape[1], z.shape[1]) + eps * np.eye(z.shape[1])
    lam, V = np.linalg.eigh(cov)
    order = np.argsort(lam)[::-1]
    lam, V = np.clip(lam[order], eps, None), V[:, order]
    for k in range(V.shape[1]):  # deterministic sign: largest component positive
        if V[np.argmax(np.abs(V[:, k])), k] < 0:
            V[:, k] *= -1
    W = V / np.sqrt(lam)[None, :]
    return mean, W, np.linalg.inv(W)


def visibility_metric(model: AutoEncoder, chart_mean: np.ndarray, W_inv: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Visibility metric ``G_bar = mean_q J(q)^T J(q)`` (paper Eq. 6).

    ``J = d vec(image) / d q`` at the training resolution, computed exactly by
    forward-mode differentiation (one Jacobian-vector product per latent
    direction): for the 2-D conditioned decoder by the compiled rasteriser's
    forward-mode pass over all states at once (:func:`lagsplat.models.decoder_jvp.render_jvp`),
    otherwise by forward-mode AD through the pure-torch tile rasteriser, which
    implements the same compositing rule as the training backend (the tests
    check the two agree). The image is in [0, 1]; ``G_bar`` is divided by the
    number of image values so it does not grow with resolution.

    Args:
        model: trained autoencoder.
        chart_mean, W_inv: whitening (see :func:`fit_whitening`).
        q: ``[N,d]`` whitened states to average over.

    Returns:
        ``(G_bar [d,d], per_sample_singular_values [N,d])``.
    """
    dec = model.decoder
    H, W = model.height, model.width
    d = dec.d
    mean_t = torch.as_tensor(chart_mean, dtype=torch.float32)
    winv_t = torch.as_tensor(W_inv, dtype=torch.float32)

    def render(qb: Tensor) -> Tensor:
        return dec(qb @ winv_t + mean_t, H, W, backend="torch").reshape(qb.shape[0], -1)

    from lagsplat.models.decoder_jvp import render_jvp, supports_render_jvp

    eye = torch.eye(d)
    compiled = supports_render_jvp(dec)

    def jacobian(qb: Tensor) -> Tensor:
        """``[B, n_pix, d]`` Jacobians at the states ``qb [B,d]``: all at once by the compiled pass, else one by one."""
        if compiled:
            cols = [render_jvp(dec, qb @ winv_t + mean_t, eye[j].expand_as(qb) @ winv_t, H, W)[1].reshape(len(qb), -1) for j in range(d)]
        else:
            cols = [torch.func.jvp(render, (qb,), (eye[j].expand_as(qb),))[1] for j in range(d)]
        return torch.stack(cols, 2).double()

    G = np.zeros((d, d))
    svals = []
    Q = torch.as_tensor(q, dtype=torch.float32)
    with torch.no_grad():
        for s in range(0, len(Q), 64 if compiled else 1):
            for J in jacobian(Q[s : s + (64 if compiled else 1)]):  # [n_pix, d] per state
                G += (J.T @ J).numpy() / J.shape[0]
                svals.append(torch.linalg.svdvals(J).numpy() / np.sqrt(J.shape[0]))
    return G / len(q), np.array(svals)


def loss_metric(G_bar: np.ndarray, rho: float = 0.01) -> np.ndarray:
    """``A = G_bar + rho lambda_max(G_bar) I``, rescaled to ``trace A = d`` (paper §3.3)."""
    G = 0.5 * (G_bar + G_bar.T)
    d = G.shape[0]
    A = G + rho * float(np.linalg.eigvalsh(G).max()) * np.eye(d)
    return A * d / np.trace(A)


def chart_continuity(q: np.ndarray, split: np.ndarray, G_bar: np.ndarray, episode: np.ndarray | None = None) -> float:
    """Jump statistic of the encoded trajectory: ``max |D^2 p| / median |D p|``.

    ``p`` is the projection of ``q`` on ``G_bar``'s most visible direction and
    ``D`` the frame difference, taken within each contiguous split segment. A
    smooth oscillation sampled at ``N`` frames per period gives about
    ``pi^2 / N`` (well below 1); a chart that folds or tears (the encoder maps
    nearby images to distant states, or the reverse) shows isolated jumps and
    values of 5 and above. Stage 2 reads velocities and accelerations off this
    trajectory, so a torn chart cannot give a correct model.

    Returns:
        The statistic (dimensionless).
    """
    lam, V = np.linalg.eigh(0.5 * (G_bar + G_bar.T))
    p = q @ V[:, np.argmax(lam)]
    d1, d2 = [], []
    for seg in segments(split, TRAIN, episode) + segments(split, HELD_OUT, episode):
        if len(seg) > 3:
            d1.append(np.abs(np.diff(p[seg])))
            d2.append(np.abs(np.diff(p[seg], 2)))
    if not d1:
        return float("nan")
    return float(np.concatenate(d2).max() / max(np.median(np.concatenate(d1)), 1e-12))


@torch.no_grad()
def build_chart(
    model: AutoEncoder, clip: Clip, n_metric_samples: int = 64, rho: float = 0.01, seed: int = 0, refine_iters: int = 0
) -> Chart:
    """Encode the clip, whiten, compute ``G_bar``, ``A`` and the AE floor.

    Args:
        model: trained autoencoder (frozen).
        clip: the clip it was trained on.
        n_metric_samples: training frames drawn (seeded) to average ``G_bar``.
        rho: ridge of the loss metric.
        seed: RNG seed of the frame draw.
        refine_iters: ``0`` (the paper's chart: the encoder's output) or the
            number of :func:`refine_latents` iterations that move each encoding
            to where the decoder draws its frame best, before the whitening;
            the AE floor is then that of the refined latents.

    Returns:
        The :class:`Chart`.
    """
    z_enc = model.encode_frames(clip.images).numpy().astype(np.float64)
    z = refine_latents(model, clip.images, z_enc, int(refine_iters))[0] if int(refine_iters) > 0 else z_enc
    tr = clip.train_idx
    mean, W, W_inv = fit_whitening(z[tr])
    q = (z - mean) @ W
    shift = float(np.sqrt((((z - z_enc) @ W) ** 2).sum(1).mean()))  # whitened units; 0 unrefined
    rng = np.random.default_rng(seed)
    pick = rng.choice(tr, size=min(n_metric_samples, len(tr)), replace=False)
    G_bar, svals = visibility_metric(model, mean, W_inv, q[np.sort(pick)])
    ae = np.empty(clip.n_frames)
    for i in range(0, clip.n_frames, 64):
        x = frames_to_tensor(clip.images[i : i + 64])
        rec = model.decode(torch.as_tensor(z[i : i + 64], dtype=torch.float32))
        ae[i : i + 64] = ((rec - x) ** 2).mean(dim=(1, 2, 3)).numpy()
    ho = clip.held_out_idx
    jump = chart_continuity(q, clip.split, G_bar, clip.episode)
    if jump > FOLD_WARNING:
        import warnings

        warnings.warn(
            f"the encoded trajectory jumps (max second difference {jump:.1f}x the median step): the latent "
            "chart may fold or tear and Stage 2 will be unreliable; consider more stage1.steps, "
            "stage1.w_nonlocal > 0, or a crop that keeps the object away from the image border",
            stacklevel=2,
        )
    return Chart(
        mean=mean,
        W=W,
        W_inv=W_inv,
        q=q,
        t=clip.t.copy(),
        split=clip.split.copy(),
        episode=clip.episode.copy(),
        u=clip.u.copy(),
        G_bar=G_bar,
        A=loss_metric(G_bar, rho),
        ae_mse=ae,
        ae_floor_train=float(ae[tr].mean()),
        ae_floor_held_out=float(ae[ho].mean()) if len(ho) else float("nan"),
        height=model.height,
        width=model.width,
        meta={
            "n_metric_samples": int(len(pick)),
            "rho": rho,
            "seed": seed,
            "G_singular_values_mean": svals.mean(0).tolist(),
            "continuity_jump_ratio": jump,
            "refine_iters": int(refine_iters),
            "refine_rms_shift": shift,
        },
    )


def save_chart(path: str | Path, chart: Chart) -> Path:
    """Write ``chart.npz`` atomically."""
    import json

    with atomic_write(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez(
                fh,
                mean=chart.mean,
                W=chart.W,
                W_inv=chart.W_inv,
                q=chart.q,
                t=chart.t,
                split=chart.split,
                episode=chart.episode,
                u=chart.u,
                G_bar=chart.G_bar,
                A=chart.A,
                ae_mse=chart.ae_mse,
                ae_floor_train=chart.ae_floor_train,
                ae_floor_held_out=chart.ae_floor_held_out,
                height=chart.height,
                width=chart.width,
                meta=np.array(json.dumps(chart.meta)),
            )
    return Path(path)


def load_chart(path: str | Path) -> Chart:
    """Read ``chart.npz``.

    Raises:
        FileNotFoundError: if the file is missing.
    """
    import json

    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: chart not found")
    with np.load(path, allow_pickle=False) as z:
        return Chart(
            mean=z["mean"],
            W=z["W"],
            W_inv=z["W_inv"],
            q=z["q"],
            t=z["t"],
            split=z["split"],
            G_bar=z["G_bar"],
            A=z["A"],
            ae_mse=z["ae_mse"],
            ae_floor_train=float(z["ae_floor_train"]),
            ae_floor_held_out=float(z["ae_floor_held_out"]),
            height=int(z["height"]),
            width=int(z["width"]),
            meta=json.loads(str(z["meta"])),
            episode=z["episode"] if "episode" in z.files else None,
            u=z["u"] if "u" in z.files else None,
        )
