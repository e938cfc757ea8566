"""Per-frame analysis-by-synthesis of the chart: each encoding moved to where the decoder draws its frame best.

Used by :func:`lagsplat.chart.build_chart` (``chart.refine_iters``) and by the
chart-quality gate's saturation check (:func:`lagsplat.chart.gate.encoder_saturation`).
"""

from __future__ import annotations

import numpy as np
import torch

from lagsplat.models.autoencoder import AutoEncoder, frames_to_tensor

__all__ = ["refine_latents"]


@torch.no_grad()
def refine_latents(
    model: AutoEncoder, frames: np.ndarray, z: np.ndarray, iters: int = 8, batch: int = 128, max_step: float = 0.25
) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame analysis-by-synthesis: move each encoding to where its own decoder draws the frame best.

    The encoder is amortised: one network for every frame, trained for the
    temporal regularity Stage 2 needs (paper §3.2 "Continuity-preserving
    encoder"), not for accuracy. Where it saturates (typically at the turning
    points, the rarest and most extreme images) the chart reads the object short
    of where the decoder places it. This minimises, per frame, the image MSE
    ``|decode(z) - frame|^2`` over ``z`` by Levenberg-Marquardt (Gauss-Newton on
    the rendered image, Jacobian by central differences), starting at the encoding,
    accepting a step only where it lowers the error, so no frame gets worse.
    Central differences use the compiled CPU renderer; the exact Jacobian by
    forward-mode AD through the torch rasteriser (as :func:`visibility_metric`)
    was measured many times slower for the same result (the measurement:
    ``docs/experiments/code_comment_history.md``).

    Args:
        model: trained autoencoder (frozen).
        frames: ``[T,H,W,3]`` uint8 frames at the training resolution.
        z: ``[T,d]`` raw encodings (the start).
        iters: Levenberg-Marquardt iterations (each ``2d + 1`` renders per frame).
        batch: frames per batch.
        max_step: largest move per iteration and per latent, in units of the
            spread (standard deviation over frames) of ``z``.

    Returns:
        ``(z_refined [T,d] float64, mse [T])``: the refined latents and their
        reconstruction MSE (pixels in [0, 1]), never above that of ``z``.

    Raises:
        ValueError: if ``frames`` and ``z`` differ in length, or ``iters < 0``.
    """
    z = np.asarray(z, np.float64)
    if len(frames) != len(z):
        raise ValueError(f"refine_latents: {len(frames)} frames but {len(z)} latents")
    if int(iters) < 0:
        raise ValueError(f"refine_latents: iters must be >= 0, got {iters!r}")
    d = z.shape[1]
    scale = torch.as_tensor(np.maximum(z.std(0), 1e-6), dtype=torch.float32)
    h, eye = 1e-2 * scale, torch.eye(d)
    out, mse = np.empty_like(z), np.empty(len(z))
    for a in range(0, len(z), batch):
        x = frames_to_tensor(frames[a : a + batch])
        zb = torch.as_tensor(z[a : a + batch], dtype=torch.float32)
        r = model.decode(zb) - x
        err = (r**2).mean(dim=(1, 2, 3))
        lam = torch.full((len(zb),), 1e-3)
        for _ in range(int(iters)):
            J = torch.stack([(model.decode(zb + h[k] * eye[k]) - model.decode(zb - h[k] * eye[k])).flatten(1) / (2 * h[k]) for k in range(d)], -1)
            JtJ = J.transpose(1, 2) @ J
            g = (J.transpose(1, 2) @ r.flatten(1)[..., None])[..., 0]
            damp = lam[:, None, None] * torch.diagonal(JtJ, dim1=1, dim2=2).mean(-1)[:, None, None] * eye
            step = torch.clamp(-torch.linalg.solve(JtJ + damp + 1e-12 * eye, g), -max_step * scale, max_step * scale)
            r_new = model.decode(zb + step) - x
            err_new = (r_new**2).mean(dim=(1, 2, 3))
            ok = err_new < err
            zb = torch.where(ok[:, None], zb + step, zb)
            r = torch.where(ok[:, None, None, None], r_new, r)
            err = torch.where(ok, err_new, err)
            lam = torch.where(ok, lam * 0.3, lam * 10.0)
        out[a : a + batch] = zb.double().numpy()
        mse[a : a + batch] = err.double().numpy()
    return out, mse
