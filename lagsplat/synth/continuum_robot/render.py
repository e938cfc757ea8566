"""Pictures of the simulated soft robot (the recordings' 32 x 32 top-lit view).

Part of :mod:`lagsplat.synth.continuum_robot` (its docstring describes the model).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import cv2
import numpy as np

from lagsplat.synth._render import (
    SUPERSAMPLE,
    Canvas,
    background,
    check_supersample,
    over,
    parse_size,
    render_frames,
)
from lagsplat.synth.continuum_robot.constants import (
    BG_GAIN,
    HALF_WIDTH,
    MOUNT_HALF_WIDTH,
    MOUNT_RGB,
    MOUNT_Y,
    RENDER_NODES,
    REST_FILL,
    RING_LENGTH,
    RING_OVERHANG,
    RING_RGB,
    SEG_RGB,
)
from lagsplat.synth.continuum_robot.model import ContinuumRobot


def _layout(robot: ContinuumRobot, W: int, H: int) -> tuple[float, float, float]:
    """``(x0, y0, px_per_m)``: mount point in output pixels and the scale."""
    L_rest = float(np.sum(np.asarray(robot.length_m) * (1.0 + robot.modal.q_rest[1::2])))
    return W / 2.0, MOUNT_Y * H, REST_FILL[robot.n_segments - 1] * H / L_rest


def _backdrop(W: int, H: int, s: int, seed: int) -> np.ndarray:
    """Dark, faintly textured background with the mount, float64 ``[H, W, 3]``."""
    cv = Canvas(W, H, s)
    cv.rect(W / 2.0 - MOUNT_HALF_WIDTH * H, 0.0, W / 2.0 + MOUNT_HALF_WIDTH * H, MOUNT_Y * H, MOUNT_RGB)
    return np.clip(over(cv.reduce(W, H), BG_GAIN * background(W, H, seed)), 0.0, 1.0)


def _fill(cv: Canvas, poly: np.ndarray, rgb: tuple[float, float, float]) -> None:
    """Fill a simple (possibly non-convex) polygon, complex vertices in output pixels, on ``cv``.

    Same placement convention as :meth:`Canvas.convex` (pixel centres at
    ``j + 0.5``, 4 fractional bits), vectorised for the many backbone vertices.
    """
    one = 1 << Canvas._SHIFT
    xy = np.stack([(poly.real * cv.s - 0.5) * one, (poly.imag * cv.s - 0.5) * one], axis=-1)
    cv2.fillPoly(cv.img, [np.round(xy).astype(np.int32)], (*rgb, 1.0), cv2.LINE_8, Canvas._SHIFT)


def _draw_robot(pts: np.ndarray, phi: np.ndarray, n: int, K: int, W: int, H: int, s: int) -> np.ndarray:
    """One frame of the arm from backbone pixels ``pts`` (complex ``[n K + 1]``) and angles; premultiplied RGBA."""
    cv = Canvas(W, H, s)
    nn = pts.shape[0]
    hw = H * (HALF_WIDTH[0] + (HALF_WIDTH[1] - HALF_WIDTH[0]) * np.arange(nn) / (nn - 1))
    normal = np.cos(phi) - 1j * np.sin(phi)  # unit normal (image right when hanging)
    left, right = pts + hw * normal, pts - hw * normal
    for i in range(n):  # each segment's outline: one side down, the other back up
        sl = slice(i * K, (i + 1) * K + 1)
        _fill(cv, np.concatenate([left[sl], right[sl][::-1]]), SEG_RGB[i])
    tip = pts[-1]
    cv.disc(tip.real, tip.imag, hw[-1], SEG_RGB[n - 1])
    if n > 1:  # connector ring at the end of segment 1
        c, t = pts[K], 1j * np.exp(-1j * phi[K])  # centre, unit tangent
        half = 0.5 * RING_LENGTH * H
        rw = hw[K] + RING_OVERHANG * H
        ring = [c - half * t + rw * normal[K], c + half * t + rw * normal[K], c + half * t - rw * normal[K], c - half * t - rw * normal[K]]
        cv.convex([(z.real, z.imag) for z in ring], RING_RGB)
    return cv.reduce(W, H)


def render_continuum_robot(
    q: Any,
    robot: ContinuumRobot,
    size: Sequence[int] = (32, 32),
    seed: int = 0,
    supersample: int = SUPERSAMPLE,
) -> np.ndarray:
    """Render the arm for a sequence of configurations (picture: module docstring).

    Args:
        q: ``[T, d]`` configurations ``(theta_1, eps_1[, theta_2, eps_2])``
            (the first ``d`` columns of :func:`simulate_continuum_robot`'s states).
        robot: the :class:`ContinuumRobot` that produced them (lengths, scale).
        size: output ``(W, H)`` pixels (each >= 16).
        seed: seed of the background's faint texture (nothing else).
        supersample: supersampling factor (>= 1).

    Returns:
        uint8 ``[T, H, W, 3]`` RGB frames.

    Raises:
        ValueError: if ``q`` is not a non-empty finite ``[T, d]`` array, or on
            a bad ``size`` / ``supersample``.
        TypeError: if ``robot`` is not a :class:`ContinuumRobot`.
    """
    if not isinstance(robot, ContinuumRobot):
        raise TypeError(f"robot must be a ContinuumRobot, got {type(robot).__name__}")
    qa = np.asarray(q, dtype=np.float64)
    if qa.ndim != 2 or qa.shape[1] != robot.d or qa.shape[0] < 1:
        raise ValueError(f"q must be a non-empty [T, {robot.d}] array of configurations, got shape {qa.shape}")
    W, H = parse_size(size, 16)
    s = check_supersample(supersample)
    r, phi = robot.backbone(qa, RENDER_NODES)
    x0, y0, scale = _layout(robot, W, H)
    pts = complex(x0, y0) + scale * r
    n, K = robot.n_segments, RENDER_NODES
    return render_frames(range(qa.shape[0]), lambda i: _draw_robot(pts[i], phi[i], n, K, W, H, s), _backdrop(W, H, s, seed))


