"""A damped pendulum with known physics, rendered as a small video clip.

The embedded default clip: every number a model should identify (natural
frequency, damping ratio, the frequency actually visible on the held-out
segment) is known exactly and stored under ``clip.meta["truth"]``.

Physics
-------
The nonlinear damped pendulum, released from rest at ``theta0``::

    theta'' + 2 zeta w0 theta' + w0^2 sin(theta) = 0,   w0 = 2 pi f_natural

integrated with ``scipy.integrate.solve_ivp`` (DOP853, ``rtol = 1e-10``) and
sampled at ``t_i = i / fps``. For small angles the free oscillation has
frequency ``f_natural sqrt(1 - zeta^2)`` and an amplitude envelope
``exp(-zeta w0 t)``; at finite amplitude the frequency is lower by about
``theta_amp^2 / 16`` (relative).

Picture
-------
Geometry is expressed in units of the frame height ``H`` (horizontal position
relative to the centre), so any frame size works: the pivot sits at
``(W/2, 0.14 H)``, the rod is ``0.58 H`` long and the bob radius ``0.09 H``;
``theta`` is measured from the downward vertical, positive to the right of the
image. For ``|theta| <= 25 deg`` the bob stays inside the frame as long as
``W >= 0.7 H``. The bob is split along the rod axis into two colours, so its
rotation with the rod is visible. The foreground is rendered at 4x the output
resolution and reduced with ``cv2.INTER_AREA`` (anti-aliasing), then
composited over a light background with a faint static texture (gradient,
low-contrast grid and seeded smooth noise).
"""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np
from scipy.integrate import solve_ivp

from lagsplat.io.clip import HELD_OUT, TRAIN, Clip
from lagsplat.timeseries import spectral_peak_frequency
from lagsplat.synth._clip import check_timing, check_train_fraction, contiguous_train_frames
from lagsplat.synth._render import (
    SUPERSAMPLE,
    Canvas,
    background,
    check_supersample,
    parse_size,
    render_frames,
)

__all__ = [
    "simulate_pendulum",
    "render_pendulum",
    "make_pendulum_clip",
    "PIVOT_Y",
    "ROD_LENGTH",
    "BOB_RADIUS",
]

#: Pivot height, rod length and bob radius, in units of the frame height.
PIVOT_Y = 0.14
ROD_LENGTH = 0.58
BOB_RADIUS = 0.09
_ROD_HALF_WIDTH = 0.018
_PIVOT_RADIUS = 0.03

# Colours, RGB in [0, 1].
_ROD_RGB = (0.25, 0.25, 0.28)
_PIVOT_RGB = (0.15, 0.15, 0.17)
_ROD_BAND_RGB = (0.95, 0.75, 0.20)
_BOB_LEFT_RGB = (0.85, 0.20, 0.15)  # left of the rod axis (seen hanging down)
_BOB_RIGHT_RGB = (0.15, 0.35, 0.85)


def simulate_pendulum(
    f_natural_hz: float,
    zeta: float,
    theta0_rad: float,
    fps: float,
    n_frames: int,
    substeps: int = 4,
) -> tuple[np.ndarray, np.ndarray]:
    """Integrate the nonlinear damped pendulum released from rest.

    ``theta'' + 2 zeta w0 theta' + w0^2 sin(theta) = 0`` with
    ``w0 = 2 pi f_natural_hz``, ``theta(0) = theta0_rad``, ``theta'(0) = 0``,
    by DOP853 (``rtol = 1e-10``, ``atol = 1e-12``), with the step limited to
    ``1 / (fps * substeps)`` seconds.

    Args:
        f_natural_hz: undamped small-angle natural frequency (Hz, > 0).
        zeta: damping ratio (0 <= zeta < 1).
        theta0_rad: release angle (rad), ``|theta0| < pi``.
        fps: sampling rate (frames per second, > 0).
        n_frames: number of samples ``T`` (>= 2).
        substeps: at least this many integrator steps per frame interval (>= 1).

    Returns:
        ``(theta, t)``: float64 ``[T]`` angles in rad and float64 ``[T]`` times
        ``t_i = i / fps`` in seconds.

    Raises:
        ValueError: on invalid arguments, or if the integrator fails.
    """
    f_n = float(f_natural_hz)
    z = float(zeta)
    th0 = float(theta0_rad)
    fps_f = float(fps)
    n = int(n_frames)
    sub = int(substeps)
    if not (math.isfinite(f_n) and f_n > 0):
        raise ValueError(f"f_natural_hz must be positive, got {f_natural_hz!r}")
    if not (math.isfinite(z) and 0.0 <= z < 1.0):
        raise ValueError(f"zeta must be in [0, 1) (under-damped), got {zeta!r}")
    if not (math.isfinite(th0) and abs(th0) < math.pi):
        raise ValueError(f"theta0_rad must satisfy |theta0| < pi, got {theta0_rad!r}")
    if not (math.isfinite(fps_f) and fps_f > 0):
        raise ValueError(f"fps must be positive, got {fps!r}")
    if n < 2 or n != n_frames:
        raise ValueError(f"n_frames must be an integer >= 2, got {n_frames!r}")
    if sub < 1:
        raise ValueError(f"substeps must be >= 1, got {substeps!r}")

    w0 = 2.0 * math.pi * f_n
    t = np.arange(n, dtype=np.float64) / fps_f

    def rhs(_t: float, y: np.ndarray) -> np.ndarray:
        th, om = y
        return np.array([om, -2.0 * z * w0 * om - w0 * w0 * math.sin(th)])

    sol = solve_ivp(
        rhs,
        (0.0, float(t[-1])),
        np.array([th0, 0.0]),
        method="DOP853",
        t_eval=t,
        rtol=1e-10,
        atol=1e-12,
        max_step=1.0 / (fps_f * sub),
    )
    if not sol.success or sol.y.shape[1] != n:
        raise ValueError(f"pendulum integration failed: {sol.message}")
    return sol.y[0].astype(np.float64), t


def _foreground(
    theta: float,
    W: int,
    H: int,
    s: int,
    rod_width: float = 2 * _ROD_HALF_WIDTH,
    rod_bands: int = 0,
    rod_above: float = 0.0,
    rod_stripes: int = 0,
) -> np.ndarray:
    """The pendulum at angle ``theta`` (rad), drawn at ``s`` x resolution and area-reduced.

    ``rod_width`` is in units of ``H``; ``rod_bands > 0`` paints the rod in that
    many equal bands of alternating colours along the rod; ``rod_stripes > 1``
    also splits it into that many stripes across its width, the cells
    alternating as on a checkerboard; ``rod_above`` (units of ``H``) extends the
    rod beyond the pivot, opposite the bob (a counter-arm, like a metronome's).

    A point of the rod moves across it (tangentially) as the pendulum swings.
    Band edges run across the rod, so they slide along themselves under that
    motion and show it only through their tilt; stripe edges run along the rod
    and show it directly (the aperture problem: only the motion across an edge
    is seen), so with stripes every point of the rod shows how far it moves.

    Returns float64 ``[H, W, 4]``: RGB premultiplied, and coverage.
    """
    cv = Canvas(W, H, s)
    px, py = W / 2.0, PIVOT_Y * H
    ux, uy = math.sin(theta), math.cos(theta)  # rod direction (y down)
    L, r, hw = ROD_LENGTH * H, BOB_RADIUS * H, 0.5 * rod_width * H
    bx, by = px + L * ux, py + L * uy
    nx, ny = uy, -ux  # unit normal pointing to the rod's image-right side when hanging

    def strip(s0: float, s1: float, n0: float = -hw, n1: float = hw) -> list[tuple[float, float]]:
        """The rod between arc positions ``s0 < s1`` (px from the pivot, + towards the bob) and normal offsets ``n0 < n1`` (px)."""
        return [
            (px + s0 * ux + n1 * nx, py + s0 * uy + n1 * ny),
            (px + s1 * ux + n1 * nx, py + s1 * uy + n1 * ny),
            (px + s1 * ux + n0 * nx, py + s1 * uy + n0 * ny),
            (px + s0 * ux + n0 * nx, py + s0 * uy + n0 * ny),
        ]

    top = -rod_above * H
    cv.convex(strip(top, L), _ROD_RGB)
    nb, ns = max(1, int(rod_bands)), max(1, int(rod_stripes))
    for k in range(nb):  # cells with an odd band + stripe index in the second colour
        for j in range(ns):
            if (k + j) % 2 == 1:
                s0, s1 = top + (L - top) * k / nb, top + (L - top) * (k + 1) / nb
                cv.convex(strip(s0, s1, -hw + 2 * hw * j / ns, -hw + 2 * hw * (j + 1) / ns), _ROD_BAND_RGB)
    cv.disc(px, py, _PIVOT_RADIUS * H, _PIVOT_RGB)
    cv.disc(bx, by, r, _BOB_LEFT_RGB)
    # Right half: the half-disc on the +normal side, i.e. angles [phi - 180, phi]
    # (OpenCV angles, degrees, y down) with phi the rod direction.
    phi = math.degrees(math.atan2(uy, ux))
    cv.sector(bx, by, r, phi - 180.0, phi, _BOB_RIGHT_RGB)
    return cv.reduce(W, H)


def _count(value: Any, name: str) -> int:
    """``value`` as a non-negative integer; ValueError naming ``name`` otherwise."""
    n = int(value)
    if n < 0 or n != value:
        raise ValueError(f"{name} must be a non-negative integer, got {value!r}")
    return n


def render_pendulum(
    theta: Sequence[float] | np.ndarray,
    size: tuple[int, int] = (64, 64),
    seed: int = 0,
    supersample: int = SUPERSAMPLE,
    rod_width: float = 2 * _ROD_HALF_WIDTH,
    rod_bands: int = 0,
    rod_above: float = 0.0,
    rod_stripes: int = 0,
) -> np.ndarray:
    """Render pendulum frames for a sequence of angles.

    Args:
        theta: ``[T]`` angles (rad) from the downward vertical; positive swings
            the bob to the right of the image.
        size: output ``(W, H)`` in pixels (each >= 8).
        seed: seed of the background's smooth noise (nothing else depends on it).
        supersample: foreground supersampling factor (>= 1; 4 by default),
            reduced with ``cv2.INTER_AREA``.
        rod_width: rod width in units of ``H`` (default 0.036, a thin rod).
        rod_bands: number of alternating colour bands along the rod (0: plain).
        rod_above: length of rod beyond the pivot, opposite the bob, units of
            ``H`` (in ``[0, PIVOT_Y)``; 0: none).
        rod_stripes: number of stripes across the rod's width, alternating
            with the bands as a checkerboard (0 or 1: none); they show the
            rod's motion across itself (see ``_foreground``).

    Returns:
        uint8 ``[T, H, W, 3]`` RGB frames.

    Raises:
        ValueError: on a non-1-D or non-finite ``theta`` or a bad ``size``.
    """
    th = np.asarray(theta, dtype=np.float64)
    if th.ndim != 1 or th.size < 1:
        raise ValueError(f"theta must be a non-empty 1-D array of angles, got shape {th.shape}")
    if not np.all(np.isfinite(th)):
        raise ValueError("theta contains NaN or inf")
    W, H = parse_size(size, 8)
    s = check_supersample(supersample)
    rw = float(rod_width)
    if not (math.isfinite(rw) and 0.0 < rw <= 2 * BOB_RADIUS):
        raise ValueError(f"rod_width must be in (0, {2 * BOB_RADIUS}] (units of the frame height), got {rod_width!r}")
    nb, ns = _count(rod_bands, "rod_bands"), _count(rod_stripes, "rod_stripes")
    ra = float(rod_above)
    if not (math.isfinite(ra) and 0.0 <= ra < PIVOT_Y):
        raise ValueError(f"rod_above must be in [0, {PIVOT_Y}) (units of the frame height), got {rod_above!r}")
    return render_frames(th, lambda angle: _foreground(float(angle), W, H, s, rw, nb, ra, ns), background(W, H, seed))


def make_pendulum_clip(
    size: Sequence[int] = (64, 64),
    fps: float = 30.0,
    duration_s: float = 20.0,
    f_natural_hz: float = 0.8,
    zeta: float = 0.02,
    theta0_deg: float = 20.0,
    train_fraction: float = 0.6,
    seed: int = 0,
    rod_width: float = 2 * _ROD_HALF_WIDTH,
    rod_bands: int = 0,
    rod_above: float = 0.0,
    rod_stripes: int = 0,
) -> Clip:
    """The synthetic damped-pendulum clip with its ground truth.

    ``T = round(duration_s * fps)`` frames at ``t_i = i / fps``; the first
    ``int(train_fraction * T)`` frames are training frames, the rest held out
    (one contiguous split). No actuation (``n_u = 0``).

    ``meta`` holds::

        source: "lagsplat.synth.pendulum"
        truth:  f_natural_hz, zeta,
                f_damped_small_angle_hz = f_natural sqrt(1 - zeta^2),
                f_observed_hz  (spectral peak of the true theta on the held-out
                                segment, lagsplat.timeseries.spectral_peak_frequency:
                                what a perfect model shows at that amplitude),
                theta0_rad, decay_rate_per_s = zeta w0
        theta:  list of the true angle per frame (rad)
        params: every argument of this function

    The defaults give 8 s (6.4 periods) of held-out motion.

    Args:
        size: output ``(W, H)`` pixels.
        fps: frame rate (Hz).
        duration_s: clip length (s).
        f_natural_hz: undamped small-angle natural frequency (Hz).
        zeta: damping ratio in ``[0, 1)``.
        theta0_deg: release angle (degrees), from rest.
        train_fraction: share of frames used for training, in ``(0, 1)``.
        seed: seed of the background texture only; everything else is fixed.
        rod_width, rod_bands, rod_above, rod_stripes: rod width (units of
            ``H``), colour bands along it, counter-arm beyond the pivot and
            stripes across it, see :func:`render_pendulum` (the defaults draw
            the toy's thin plain rod; a wide checkered rod shows every point's
            motion, as the force ground truth ``conf/system/pendulum_force.yaml`` needs).

    Returns:
        A validated :class:`~lagsplat.io.clip.Clip`.

    Raises:
        ValueError: on invalid arguments (including a split that leaves fewer
            than 2 training or 8 held-out frames).
    """
    fps_f, dur = check_timing(fps, duration_s)
    tf = check_train_fraction(train_fraction)
    W, H = parse_size(size)
    T = int(round(dur * fps_f))
    n_train = contiguous_train_frames(tf, T)

    theta0 = math.radians(float(theta0_deg))
    theta, t = simulate_pendulum(f_natural_hz, zeta, theta0, fps_f, T)
    images = render_pendulum(
        theta, size=(W, H), seed=seed, rod_width=rod_width, rod_bands=rod_bands, rod_above=rod_above, rod_stripes=rod_stripes
    )

    split = np.full(T, HELD_OUT, np.int8)
    split[:n_train] = TRAIN
    f_obs = spectral_peak_frequency(theta[n_train:], 1.0 / fps_f)
    w0 = 2.0 * math.pi * float(f_natural_hz)
    meta: dict[str, Any] = {
        "source": "lagsplat.synth.pendulum",
        "truth": {
            "f_natural_hz": float(f_natural_hz),
            "zeta": float(zeta),
            "f_damped_small_angle_hz": float(f_natural_hz) * math.sqrt(1.0 - float(zeta) ** 2),
            "f_observed_hz": float(f_obs),
            "theta0_rad": theta0,
            "decay_rate_per_s": float(zeta) * w0,
        },
        "theta": [float(v) for v in theta],
        "params": {
            "size": [W, H],
            "fps": fps_f,
            "duration_s": dur,
            "f_natural_hz": float(f_natural_hz),
            "zeta": float(zeta),
            "theta0_deg": float(theta0_deg),
            "train_fraction": tf,
            "seed": int(seed),
            "rod_width": float(rod_width),
            "rod_bands": int(rod_bands),
            "rod_above": float(rod_above),
            "rod_stripes": int(rod_stripes),
        },
    }
    clip = Clip(images=images, t=t, split=split, meta=meta)
    return clip.validate("lagsplat.synth.pendulum")
