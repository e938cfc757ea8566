"""An effect's size in pixels of the video, read through the decoder (paper Eq. 9: ``mu_i(q) = c_i + J_i q``).

The diagnosis fits its candidates in the whitened chart, whose unit is one standard deviation of the
encoded motion. Where the report has the Stage-1 autoencoder, the decoder's kinematics turn a chart
position or length into pixels (through the main camera for a 3-D decoder,
:class:`~lagsplat.diagnose.screen.ScreenKinematics`): the object is the set of primitives that move (``|J_i|`` at least
``moving_fraction`` of the 99th percentile, as in :mod:`lagsplat.diagnose.localise`), its position at
``q`` their opacity-weighted mean ``mu_i(q)``, and one chart unit along a direction ``e`` the weighted
mean of ``|J_i e|``. Positions are given in the working frame and, through the clip's crop and resize
(``clip.meta``), in the source video's pixels.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import torch

__all__ = ["object_position_px", "px_per_unit", "source_px_per_px", "to_source_px", "add_pixel_sizes"]


def _moving_weights(tr: Any, q: np.ndarray, moving_fraction: float) -> torch.Tensor:
    """``[K]`` weights of the moving primitives at ``q``: opacity times ``|J_i|`` (pixel Jacobians), zero for the still ones."""
    qt = torch.as_tensor(np.asarray(q, np.float32).reshape(1, -1))
    motion = torch.linalg.matrix_norm(tr.pixel_jacobians(qt))
    if float(motion.max()) <= 0:
        raise ValueError("the decoder moves no primitive: no pixel scale")
    moving = motion >= moving_fraction * torch.quantile(motion, 0.99)
    return tr.opacity(qt)[0] * motion * moving


def object_position_px(tr: Any, q: np.ndarray, moving_fraction: float = 0.1) -> np.ndarray:
    """The moving object's position ``[2]`` (x, y; px of the working frame) at the whitened state ``q [d]``.

    Args:
        tr: :class:`lagsplat.diagnose.screen.ScreenKinematics` of the autoencoder and chart.
        q: ``[d]`` whitened chart position.
        moving_fraction: share of the 99th percentile of ``|J_i|`` from which a primitive moves.

    Raises:
        ValueError: if no primitive moves.
    """
    w = _moving_weights(tr, q, moving_fraction)
    mu = tr.positions(torch.as_tensor(np.asarray(q, np.float32).reshape(1, -1)))
    return (w[:, None] * mu).sum(0).numpy() / max(float(w.sum()), 1e-30)


def px_per_unit(tr: Any, e: np.ndarray, q: np.ndarray | None = None, moving_fraction: float = 0.1) -> float:
    """Pixels the object moves per unit of the whitened chart along the unit direction ``e [d]`` (weighted mean of ``|J_i e|``).

    Raises:
        ValueError: if no primitive moves.
    """
    e = np.asarray(e, np.float32)
    q = np.zeros_like(e) if q is None else q
    w = _moving_weights(tr, q, moving_fraction)
    J = tr.pixel_jacobians(torch.as_tensor(np.asarray(q, np.float32).reshape(1, -1)))
    step = torch.linalg.vector_norm(torch.einsum("kij,j->ki", J, torch.as_tensor(e)), dim=1)
    return float((w * step).sum() / max(float(w.sum()), 1e-30))


def source_px_per_px(meta: Mapping[str, Any] | None) -> np.ndarray | None:
    """Source-video pixels per working-frame pixel ``[2]`` (x, y), through ``meta["crop"]`` (x0, y0, x1, y1) and
    ``meta["resize"]`` (width, height); ``None`` when the clip records neither."""
    crop, size = (meta or {}).get("crop"), (meta or {}).get("resize")
    if crop is None or size is None:
        return None
    x0, y0, x1, y1 = (float(v) for v in crop)
    return np.array([(x1 - x0) / float(size[0]), (y1 - y0) / float(size[1])])


def to_source_px(xy: np.ndarray, meta: Mapping[str, Any]) -> np.ndarray | None:
    """Working-frame pixels ``[2]`` to the source video's (:func:`source_px_per_px`, offset by the crop's corner);
    ``None`` when the clip records neither crop nor resize."""
    k = source_px_per_px(meta)
    return None if k is None else np.array([float(meta["crop"][0]), float(meta["crop"][1])]) + np.asarray(xy, float) * k


def add_pixel_sizes(diagnosis: Any, tr: Any, meta: Mapping[str, Any] | None = None) -> None:
    """Add ``interpretation["in_pixels"]`` (and a sentence to its ``text``) to each accepted effect where the chart allows.

    An end stop: the object's position at contact (``s_stop`` along the effect's direction). Dry
    friction: the amplitude it takes off per cycle (``4 mu / k``) in pixels of motion. Other effects
    have no length to convert and are left as they are.

    Args:
        diagnosis: the :class:`~lagsplat.diagnose.diagnosis.Diagnosis` (its ``effects`` are updated in place).
        tr: :class:`lagsplat.diagnose.screen.ScreenKinematics` of the autoencoder and chart.
        meta: the clip's ``meta`` (crop and resize, for source pixels).
    """
    for fit in diagnosis.effects:
        it, e = fit.interpretation, np.asarray(fit.direction, np.float64)
        try:
            if fit.effect == "end_stop":
                xy = object_position_px(tr, float(it["s_stop"]) * e)
                src = to_source_px(xy, meta or {})
                px = {"stop_xy_px": [float(v) for v in xy], "stop_xy_source_px": None if src is None else [float(v) for v in src]}
                at = f"({xy[0]:.0f}, {xy[1]:.0f}) px of the working frame" + ("" if src is None else f", ({src[0]:.0f}, {src[1]:.0f}) px of the source video")
                it["in_pixels"], it["text"] = px, f"{it.get('text', '')}; the object touches the stop at {at}"
            elif fit.effect == "coulomb" and np.isfinite(it.get("amplitude_loss_per_cycle", np.nan)):
                loss = float(it["amplitude_loss_per_cycle"]) * px_per_unit(tr, e)
                it["in_pixels"], it["text"] = {"amplitude_loss_per_cycle_px": loss}, f"{it.get('text', '')} ({loss:.1f} px of motion per cycle)"
        except (ValueError, KeyError):
            continue
