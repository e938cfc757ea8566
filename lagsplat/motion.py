"""Which pixels of a clip move, change, or stay still: masks from the temporal standard deviation.

Used by Stage 1 (the static-pixel prior, :func:`lagsplat.train.stage1.static_pixels`)
and by the force-transport checks (:mod:`lagsplat.forces.checks`, paper §3.4):
the background check probes forces only on pixels that nothing moving can reach.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import distance_transform_edt, gaussian_filter

__all__ = ["motion_masks"]


def motion_masks(
    images: np.ndarray, sigma: float, moving_frac: float = 0.25, static_factor: float = 1.5
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Moving and static pixels of a clip, from the temporal standard deviation.

    The per-pixel std of the intensities (smoothed by a 1 px Gaussian, so
    isolated noisy pixels do not count) marks a pixel as *moving* if it reaches
    ``moving_frac`` of the largest, *changing* if it exceeds ``static_factor``
    times the noise floor (the 10th percentile of the std over the frame, at
    least half a grey level), and
    *static* if nothing within ``3 sigma`` px changes (the brush cannot reach
    anything that moves). Slow brightness changes that follow the object
    (exposure, reflections, shadows) count as changing.

    Args:
        images: uint8 ``[T,H,W,3]`` frames.
        sigma: brush radius, px.
        moving_frac: share of the largest std above which a pixel moves.
        static_factor: multiple of the noise floor above which a pixel changes.

    Returns:
        ``(moving [H,W] bool, static [H,W] bool, std [H,W] float)`` (std of
        intensities in [0, 1], channel mean, smoothed).

    Raises:
        ValueError: if ``images`` is not ``[T,H,W,3]`` with ``T >= 2`` or nothing moves.
    """
    if images.ndim != 4 or images.shape[-1] != 3 or images.shape[0] < 2:
        raise ValueError(f"need frames [T,H,W,3] with T >= 2, got {images.shape}")
    std = gaussian_filter(images.astype(np.float32).std(0).mean(-1) / 255.0, 1.0)
    top = float(std.max())
    if top <= 0:
        raise ValueError("nothing moves in the clip (all pixels constant)")
    moving = std >= moving_frac * top
    # the sensor-noise level of pixels that never change; at least half a grey
    # level (noise-free synthetic frames have std 0 there)
    floor = max(float(np.percentile(std, 10)), 0.5 / 255.0)
    changing = std > static_factor * floor
    static = distance_transform_edt(~changing) >= 3.0 * sigma
    return moving, static, std
