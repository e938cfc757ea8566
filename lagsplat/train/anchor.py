"""An anchored start for Stage 1: the encoder first follows the object's path, and primitives start on it.

On a clip whose moving object is small against a textured scene (a bob of a few
pixels before a railing), a Stage-1 start from one frame leaves the object out:
the primitives drawn from the first frame sit on the scene, the untrained
encoder's encodings do not follow the object, so a primitive placed on the
object at one state is shown at states where the object is elsewhere, costs
more than it gains and fades; the decoder ends up drawing the scene alone
(decoder motion far below the autoencoder floor, paper §3.2's gate fails).

The anchored start breaks that circle from the frames themselves, before any
training step of the autoencoder:

1. :func:`object_path`: the centroid of each training frame's departure from
   the per-pixel median of the frames, projected on its principal direction,
   standardised: a coordinate that follows the object (the same path the
   clip's preparation reads, :mod:`lagsplat.prepare`);
2. :func:`prefit_encoder`: the encoder's first latent regresses that
   coordinate for a few hundred steps (mean squared error; the other latents
   are left to the joint training);
3. :func:`anchor_primitives`: a share of the primitives is placed on the
   departure of frames spread over the clip, each at that frame's encoding,
   with the frame's colour there and a latent extent a fraction of the
   encodings' spread, in front of the others (the 2-D rasteriser composites in
   index order), so the decoder draws the object where the encoder says it is
   from the first step.

The joint training of paper Eq. (3) then proceeds as usual: nothing here is a
loss term of the trained model, and the chart is built from the trained
encoder alone (paper §3.2).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor, nn

from lagsplat.models.decoder import ConditionedGaussians
from lagsplat.prepare.frequency import principal_path

__all__ = ["departure", "object_path", "prefit_encoder", "anchor_primitives", "DEPARTURE_FRACTION", "ANCHOR_SIGMA", "SCENE_SIGMA"]

#: Pixels whose departure from the median is below this fraction of the frame's largest are left out of its centroid.
DEPARTURE_FRACTION = 0.25
#: Latent extent of an anchored primitive, as a fraction of the encodings' spread.
ANCHOR_SIGMA = 0.2
#: Latent extent of the other primitives (the scene's), in units of the encodings' spread: a scene whose primitives
#: are open over the whole range draws the same at every state, so it does not pull every frame to one encoding.
SCENE_SIGMA = 3.0


def departure(X: Tensor) -> Tensor:
    """``[N,H,W]`` departure of each frame from the per-pixel median of the frames (channel mean of ``|x - median|``).

    Args:
        X: ``[N,3,H,W]`` frames in [0, 1].
    """
    return (X - X.median(0).values).abs().mean(1)


def object_path(X: Tensor, D: Tensor | None = None) -> Tensor:
    """``[N]`` a standardised coordinate of the moving object along its path (module docstring, step 1).

    Each frame's departure from the median (:func:`departure`), kept where it exceeds
    :data:`DEPARTURE_FRACTION` of that frame's largest, gives a centroid ``(x, y)`` (px); the
    centroids are projected on their principal direction (:func:`lagsplat.prepare.frequency.principal_path`)
    and scaled to unit standard deviation. A frame without departure keeps the mean position.

    Args:
        X: ``[N,3,H,W]`` frames in [0, 1], N >= 2.
        D: their :func:`departure`, if already computed.

    Raises:
        ValueError: for fewer than 2 frames.
    """
    if X.shape[0] < 2:
        raise ValueError(f"object_path needs at least 2 frames, got {X.shape[0]}")
    D = departure(X) if D is None else D
    D = torch.where(D >= DEPARTURE_FRACTION * D.amax((1, 2), keepdim=True), D, torch.zeros(()))
    _, H, W = D.shape
    ys, xs = torch.meshgrid(torch.arange(H, dtype=D.dtype), torch.arange(W, dtype=D.dtype), indexing="ij")
    mass = D.sum((1, 2))
    ok = mass > 0
    c = torch.stack([(D * xs).sum((1, 2)), (D * ys).sum((1, 2))], 1) / mass.clamp_min(1e-12)[:, None]  # [N,2]
    c = torch.where(ok[:, None], c, c[ok].mean(0) if ok.any() else torch.zeros(2))
    s = torch.from_numpy(principal_path(c.double().numpy())[0]).float()
    sd = s.std()
    return s / sd if float(sd) > 0 else s


def prefit_encoder(enc: nn.Module, X: Tensor, target: Tensor, steps: int, lr: float, batch: int, rng: np.random.Generator) -> float:
    """Regress the encoder's first latent on ``target`` (module docstring, step 2); returns the last batch's mean squared error.

    Args:
        enc: the encoder (``[B,3,H,W] -> [B,d]``), trained in place.
        X: ``[N,3,H,W]`` training frames.
        target: ``[N]`` the coordinate to follow (:func:`object_path`).
        steps: Adam steps (0: nothing is done, the result is ``nan``).
        lr: learning rate.
        batch: frames per step.
        rng: the batch sampler.
    """
    if steps <= 0:
        return float("nan")
    opt = torch.optim.Adam(enc.parameters(), lr=lr)
    loss = torch.full((), float("nan"))
    for _ in range(steps):
        idx = torch.as_tensor(rng.choice(len(X), size=min(batch, len(X)), replace=False))
        loss = (enc(X[idx])[:, 0] - target[idx]).pow(2).mean()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
    return float(loss.detach())


@torch.no_grad()
def anchor_primitives(
    dec: ConditionedGaussians, X: Tensor, z: Tensor, share: float, sigma_xy: float, generator: torch.Generator, n_frames: int = 16,
    D: Tensor | None = None,
) -> int:
    """Place ``share`` of the primitives on the moving object of ``n_frames`` frames spread over the clip (module docstring, step 3).

    The primitives chosen are the first ``round(share K)``: the 2-D rasteriser composites front to back in index
    order, so they are drawn in front of the scene's primitives (behind them they would be hidden where they overlap); each frame takes an equal number, at pixels drawn in
    proportion to the frame's departure from the median (:func:`departure`), at the frame's encoding ``z[j]``,
    with the frame's colour there, latent extent :data:`ANCHOR_SIGMA` times the encodings' spread, spatial
    extent ``sigma_xy`` and opacity 0.5. The cross-covariance of position and latent starts at zero.

    Args:
        dec: a 2-D conditioned decoder, initialised (:meth:`~lagsplat.models.decoder.ConditionedGaussians.init_from_frame`).
        X: ``[N,3,H,W]`` training frames.
        z: ``[N,d]`` their encodings.
        share: fraction of the primitives placed, in [0, 1].
        sigma_xy: spatial extent in the decoder's units.
        generator: the RNG.
        n_frames: frames the primitives are spread over (at most N).
        D: the frames' :func:`departure`, if already computed.

    Returns:
        The number of primitives placed.
    """
    n = int(round(share * dec.K))
    if n <= 0:
        return 0
    N, _, H, W = X.shape
    frames = np.unique(np.linspace(0, N - 1, min(n_frames, N, n)).round().astype(int))
    D = departure(X) if D is None else D
    per = np.array_split(np.arange(n), len(frames))  # the first rows: in front (the 2-D rasteriser composites in index order)
    zs = z.std(0).clamp_min(1e-3)
    rest = torch.arange(n, dec.K)  # the scene's primitives: open over the whole range of the encodings
    dec.mu_q[rest] = z.mean(0).expand(len(rest), -1)
    dec.L_raw[rest] = dec._raw_diagonal(SCENE_SIGMA * zs, sigma_xy, len(rest))
    for j, rows in zip(frames, per):
        if len(rows) == 0:
            continue
        rows_t = torch.as_tensor(rows)
        prob = D[j].flatten().clamp_min(0) + 1e-12
        idx = torch.multinomial(prob, len(rows), replacement=True, generator=generator)
        dec.mu_raw[rows_t] = dec.placement_raw(idx, H, W, generator, None, None)
        dec.mu_q[rows_t] = z[j].expand(len(rows), -1)
        dec.L_raw[rows_t] = dec._raw_diagonal(ANCHOR_SIGMA * zs, sigma_xy, len(rows))
        dec.logit_color[rows_t] = torch.logit(X[j][:, idx // W, idx % W].T.clamp(0.01, 0.99))
        dec.logit_alpha[rows_t] = 0.0
    return n
