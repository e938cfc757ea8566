"""The picture pipeline shared by the synthetic clips (:mod:`~lagsplat.synth.pendulum`, :mod:`~lagsplat.synth.coupled_carts`).

Moving shapes are filled with OpenCV on a :class:`Canvas` at ``s`` x the
output resolution (no anti-aliasing there, 4 fractional bits for sub-pixel
placement), area-reduced with ``cv2.INTER_AREA`` (the anti-aliasing: coverage
comes from the reduction) and composited, premultiplied, over an opaque
static background (:func:`background`: light, with a faint texture). Frames
are uint8 RGB.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import cv2
import numpy as np

#: Default supersampling factor of the renderers.
SUPERSAMPLE = 4

_BG_RGB = (0.90, 0.90, 0.88)  # RGB in [0, 1]

RGB = tuple[float, float, float]


def parse_size(size: Any, minimum: int | None = None) -> tuple[int, int]:
    """``(W, H)`` as two ints from a ``(W, H)`` pair, each at least ``minimum`` (unchecked if ``None``).

    Raises:
        ValueError: if ``size`` is not a pair of integers, or a side is below ``minimum``.
    """
    try:
        W, H = (int(v) for v in size)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"size must be (W, H), got {size!r}") from exc
    if minimum is not None and (W < minimum or H < minimum):
        raise ValueError(f"size must be at least ({minimum}, {minimum}), got {(W, H)}")
    return W, H


def check_supersample(supersample: Any) -> int:
    """The supersampling factor as an int.

    Raises:
        ValueError: if it is below 1.
    """
    s = int(supersample)
    if s < 1:
        raise ValueError(f"supersample must be >= 1, got {supersample!r}")
    return s


def background(W: int, H: int, seed: int) -> np.ndarray:
    """Light, faintly textured static background, float64 ``[H, W, 3]`` in [0, 1]."""
    y = (np.arange(H) + 0.5) / H
    x = (np.arange(W) + 0.5) / W
    bg = np.empty((H, W, 3), np.float64)
    bg[:] = np.asarray(_BG_RGB)
    # Vertical gradient (slightly darker towards the bottom) and a faint diagonal tint.
    bg -= 0.04 * y[:, None, None]
    bg[..., 2] += 0.015 * (x[None, :] - 0.5)
    # Low-contrast grid, every 1/8 of the height, about one output pixel wide.
    pitch = H / 8.0
    gx = np.abs(((np.arange(W) + 0.5 - W / 2.0) / pitch + 0.5) % 1.0 - 0.5) * pitch
    gy = np.abs(((np.arange(H) + 0.5) / pitch + 0.5) % 1.0 - 0.5) * pitch
    line = np.maximum(np.clip(1.0 - gx, 0, 1)[None, :], np.clip(1.0 - gy, 0, 1)[:, None])
    bg -= 0.025 * line[..., None]
    # Seeded smooth noise (the only thing the seed changes).
    rng = np.random.default_rng(int(seed))
    coarse = rng.standard_normal((6, 6, 3)).astype(np.float32)
    smooth = cv2.resize(coarse, (W, H), interpolation=cv2.INTER_CUBIC).astype(np.float64)
    bg += 0.012 * smooth
    return np.clip(bg, 0.0, 1.0)


class Canvas:
    """An RGBA float32 canvas at ``s`` x resolution, drawn in output-pixel units.

    Every shape is painted opaque (coverage 1), so the colour channels stay
    premultiplied; :meth:`reduce` gives the anti-aliased layer.
    """

    _SHIFT = 4  # fractional bits for sub-pixel placement

    def __init__(self, W: int, H: int, s: int) -> None:
        self.s = s
        self.img = np.zeros((H * s, W * s, 4), np.float32)

    def _pt(self, x: float, y: float) -> tuple[int, int]:
        # Output-pixel units (centres at j + 0.5) -> supersampled OpenCV units
        # (centres at integers), in fixed point.
        one = 1 << self._SHIFT
        return (round((x * self.s - 0.5) * one), round((y * self.s - 0.5) * one))

    def _len(self, r: float) -> int:
        return round(r * self.s * (1 << self._SHIFT))

    def convex(self, points: Sequence[tuple[float, float]], rgb: RGB) -> None:
        """Fill the convex polygon with these vertices (output-pixel units)."""
        poly = np.array([self._pt(x, y) for x, y in points], np.int32)
        cv2.fillConvexPoly(self.img, poly, (*rgb, 1.0), cv2.LINE_8, self._SHIFT)

    def rect(self, x0: float, y0: float, x1: float, y1: float, rgb: RGB) -> None:
        """Fill the axis-aligned rectangle with corners ``(x0, y0)``, ``(x1, y1)``."""
        self.convex([(x0, y0), (x1, y0), (x1, y1), (x0, y1)], rgb)

    def disc(self, x: float, y: float, r: float, rgb: RGB) -> None:
        """Fill the disc of radius ``r`` centred at ``(x, y)``."""
        cv2.circle(self.img, self._pt(x, y), self._len(r), (*rgb, 1.0), -1, cv2.LINE_8, self._SHIFT)

    def sector(self, x: float, y: float, r: float, start_deg: float, end_deg: float, rgb: RGB) -> None:
        """Fill the sector of the disc between two OpenCV angles (degrees, y down)."""
        R = self._len(r)
        cv2.ellipse(self.img, self._pt(x, y), (R, R), 0.0, start_deg, end_deg, (*rgb, 1.0), -1, cv2.LINE_8, self._SHIFT)

    def reduce(self, W: int, H: int) -> np.ndarray:
        """Area-reduce to ``[H, W, 4]`` float64 (premultiplied RGB, coverage)."""
        img = self.img
        if self.s > 1:
            img = cv2.resize(img, (W, H), interpolation=cv2.INTER_AREA)
        return img.astype(np.float64)


def over(fg: np.ndarray, bg: np.ndarray) -> np.ndarray:
    """Premultiplied ``fg`` ``[H, W, 4]`` over opaque ``bg`` ``[H, W, 3]``."""
    return fg[..., :3] + (1.0 - fg[..., 3:4]) * bg


def render_frames(states: Sequence[Any] | np.ndarray, draw: Callable[[Any], np.ndarray], back: np.ndarray) -> np.ndarray:
    """One uint8 frame per state: ``draw(state)`` (premultiplied ``[H, W, 4]``) over ``back`` ``[H, W, 3]``.

    Returns:
        uint8 ``[len(states), H, W, 3]`` RGB frames.
    """
    out = np.empty((len(states), *back.shape), np.uint8)
    for i, state in enumerate(states):
        out[i] = np.round(np.clip(over(draw(state), back), 0.0, 1.0) * 255.0).astype(np.uint8)
    return out
