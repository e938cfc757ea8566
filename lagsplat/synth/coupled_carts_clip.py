"""Two spring-coupled carts (:mod:`lagsplat.synth.coupled_carts`) drawn as a video clip with its ground truth.

Picture
-------
Horizontal geometry is in units of the frame width ``W``, vertical geometry
in units of the frame height ``H``, so any frame size works. Cart 1 (red)
runs on a rail at ``y = 0.38 H`` (it occupies the upper half of the frame),
cart 2 (blue) on a rail at ``y = 0.86 H`` (lower half); at rest both are
centred at ``x = W / 2``, and a displacement ``x_j`` moves cart ``j`` by
``x_j W`` (positive to the right). Each cart is a ``0.18 W x 0.17 H``
rectangle with a dark outline on two dark wheels. The rails and the end walls
are static; the springs are not drawn (a deforming spring would be a second,
non-rigid moving object in the picture). As in :mod:`lagsplat.synth.pendulum`,
shapes are rendered at 4x the output resolution, reduced with
``cv2.INTER_AREA`` and composited over the same light, faintly textured
static background.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from lagsplat.io.clip import HELD_OUT, TRAIN, Clip, segments
from lagsplat.timeseries import spectral_peak_frequency
from lagsplat.synth._clip import check_timing, check_train_fraction, contiguous_train_frames
from lagsplat.synth._render import (
    SUPERSAMPLE,
    Canvas,
    background,
    check_supersample,
    over,
    parse_size,
    render_frames,
)

from lagsplat.synth.coupled_carts import CART_HEIGHT, CART_WIDTH, MAX_DISPLACEMENT, RAIL_Y, CoupledCarts, as_pair, simulate_coupled_carts

__all__ = ["render_coupled_carts", "make_coupled_carts_clip"]

_WALL_WIDTH = 0.035  # units of W
_WALL_HEIGHT = 0.27  # units of H, above the rail
_RAIL_THICKNESS = 0.025  # units of H, below the rail line
_BODY_LIFT = 0.06  # body bottom above the rail, units of H
_WHEEL_RADIUS = 0.045  # units of H
_WHEEL_OFFSET = 0.27  # wheel centres at +- this fraction of the cart width
_OUTLINE = 0.025  # units of H

# Colours, RGB in [0, 1].
_CART_RGB = ((0.86, 0.16, 0.12), (0.14, 0.30, 0.86))  # cart 1 red, cart 2 blue
_OUTLINE_RGB = (0.12, 0.12, 0.14)
_WHEEL_RGB = (0.20, 0.20, 0.22)
_RAIL_RGB = (0.35, 0.35, 0.37)
_WALL_RGB = (0.45, 0.42, 0.38)


def _backdrop(W: int, H: int, s: int, seed: int) -> np.ndarray:
    """Background with the static rails and end walls, float64 ``[H, W, 3]`` in [0, 1]."""
    cv = Canvas(W, H, s)
    ww = _WALL_WIDTH * W
    for ry in RAIL_Y:
        y = ry * H
        cv.rect(ww, y, W - ww, y + _RAIL_THICKNESS * H, _RAIL_RGB)
        cv.rect(0.0, y - _WALL_HEIGHT * H, ww, y + _RAIL_THICKNESS * H, _WALL_RGB)
        cv.rect(W - ww, y - _WALL_HEIGHT * H, W, y + _RAIL_THICKNESS * H, _WALL_RGB)
    # Every painted pixel has coverage 1, so the colours are premultiplied.
    return np.clip(over(cv.reduce(W, H), background(W, H, seed)), 0.0, 1.0)


def _carts(x: np.ndarray, W: int, H: int, s: int) -> np.ndarray:
    """Both carts at displacements ``x`` ``[2]``: premultiplied RGBA ``[H, W, 4]``."""
    cv = Canvas(W, H, s)
    hw, bh, ol = 0.5 * CART_WIDTH * W, CART_HEIGHT * H, _OUTLINE * H
    for j, ry in enumerate(RAIL_Y):
        cx = (0.5 + float(x[j])) * W
        y = ry * H
        wr = _WHEEL_RADIUS * H
        for sgn in (-1.0, 1.0):
            cv.disc(cx + sgn * _WHEEL_OFFSET * 2.0 * hw, y - wr, wr, _WHEEL_RGB)
        top, bottom = y - _BODY_LIFT * H - bh, y - _BODY_LIFT * H
        cv.rect(cx - hw, top, cx + hw, bottom, _OUTLINE_RGB)
        cv.rect(cx - hw + ol, top + ol, cx + hw - ol, bottom - ol, _CART_RGB[j])
    return cv.reduce(W, H)


def render_coupled_carts(
    x: Sequence[Sequence[float]] | np.ndarray,
    size: Sequence[int] = (64, 64),
    seed: int = 0,
    supersample: int = SUPERSAMPLE,
) -> np.ndarray:
    """Render the two carts for a sequence of displacements.

    Args:
        x: ``[T, 2]`` displacements of cart 1 (red, upper rail) and cart 2
            (blue, lower rail) from the frame centre, in units of the frame
            width, positive to the right; ``|x| <= MAX_DISPLACEMENT`` (0.35).
        size: output ``(W, H)`` in pixels (each >= 16).
        seed: seed of the background's smooth noise (nothing else depends on it).
        supersample: supersampling factor (>= 1; 4 by default), reduced with
            ``cv2.INTER_AREA``.

    Returns:
        uint8 ``[T, H, W, 3]`` RGB frames.

    Raises:
        ValueError: if ``x`` is not a non-empty finite ``[T, 2]`` array, a
            displacement exceeds ``MAX_DISPLACEMENT`` (the cart would hit the
            end wall), or ``size`` / ``supersample`` is invalid.
    """
    xs = np.asarray(x, dtype=np.float64)
    if xs.ndim != 2 or xs.shape[1] != 2 or xs.shape[0] < 1:
        raise ValueError(f"x must be a non-empty [T, 2] array of cart displacements, got shape {xs.shape}")
    if not np.all(np.isfinite(xs)):
        raise ValueError("x contains NaN or inf")
    peak = float(np.max(np.abs(xs)))
    if peak > MAX_DISPLACEMENT * (1.0 + 1e-9):  # tolerate rounding of a scaled peak
        raise ValueError(
            f"displacement {peak:.3f} frame widths exceeds MAX_DISPLACEMENT = {MAX_DISPLACEMENT} "
            "(the cart would run into the end wall)"
        )
    W, H = parse_size(size, 16)
    s = check_supersample(supersample)
    return render_frames(xs, lambda xi: _carts(xi, W, H, s), _backdrop(W, H, s, seed))


def _episode_start(system: CoupledCarts, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Seeded initial state exciting both modes comparably (before amplitude scaling).

    Mode ``i`` gets the modal coordinate ``q_i(t) = a_i exp(-zeta_i w_i t)
    cos(w_di t - phi_i)`` with a uniform random phase ``phi_i`` and ``a_i`` such
    that the mode alone would move its more-moving cart by ``r_i``, ``r_i``
    uniform in ``[0.6, 1]``. Returns ``(x0, v0, a)``.
    """
    Phi = system.mode_shapes
    r = rng.uniform(0.6, 1.0, 2)
    phi = rng.uniform(0.0, 2.0 * math.pi, 2)
    a = r / np.max(np.abs(Phi), axis=0)
    zw = system.decay_rates
    wd = 2.0 * math.pi * system.f_modes_damped_hz
    q0 = a * np.cos(phi)
    dq0 = a * (-zw * np.cos(phi) + wd * np.sin(phi))
    return Phi @ q0, Phi @ dq0, a


def make_coupled_carts_clip(
    size: Sequence[int] = (64, 64),
    fps: float = 30.0,
    duration_s: float = 20.0,
    f_modes_hz: Sequence[float] = (0.6, 1.0),
    zeta: float | Sequence[float] = (0.02, 0.015),
    masses: Sequence[float] = (1.0, 1.5),
    wall_ratio: float = 1.0,
    amplitude: float = 0.25,
    n_episodes: int = 4,
    held_out_episodes: int = 1,
    train_fraction: float | None = None,
    seed: int = 0,
) -> Clip:
    """The synthetic coupled-carts clip (several recordings) with its exact modal truth.

    ``n_episodes`` recordings of one system (:meth:`CoupledCarts.from_modes`),
    each ``T_e = round(duration_s * fps)`` frames long and started from its own
    seeded state that excites both modes with comparable amplitude (random
    phases, modal amplitudes within a factor 0.6 of each other, see
    ``meta["episodes"]``), scaled so that the largest cart displacement of the
    episode is ``amplitude`` frame widths. The recordings are stored back to
    back: ``episode`` is the recording index and ``t_i = i / fps`` over the
    whole clip (the step between two episodes is one frame interval, though
    the state jumps; no window may cross an ``episode`` boundary).

    Split rule:

    * ``n_episodes > 1``: the last ``held_out_episodes`` recordings are
      entirely ``HELD_OUT``, the others entirely ``TRAIN``; ``train_fraction``
      is ignored (it is checked and recorded, but episodes define the split).
    * ``n_episodes == 1``: ``train_fraction`` is required and the first
      ``int(train_fraction * T)`` frames are ``TRAIN``, the rest ``HELD_OUT``
      (the pendulum's contiguous split); ``held_out_episodes`` is ignored.

    With the defaults, 4 x 20 s at 30 fps (2400 frames); the held-out
    recording shows 12 periods of the slow mode. No actuation (``n_u = 0``).

    ``meta`` holds::

        source:  "lagsplat.synth.coupled_carts"
        truth:   f_modes_hz         undamped modal natural frequencies (Hz), ascending
                 zeta_modes         modal damping ratios
                 f_modes_damped_hz  f_i sqrt(1 - zeta_i^2)
                 decay_rates_per_s  zeta_i w_i
                 mass, stiffness, damping   [2][2] matrices M, K, C
                 mode_shapes        [2][2] Phi, column i = mode i, Phi^T M Phi = I
                 springs            [k1, k2, k3] (N/m)
                 f_observed_hz      spectral peak (lagsplat.timeseries.spectral_peak_frequency)
                                    of the true cart-1 displacement on the longest held-out
                                    segment (the first of equal ones), the segment the
                                    single-frequency evaluator measures
        x:       [[x1, x2]] true displacements per frame (frame widths)
        episodes: per recording: frames [start, stop), x0 (frame widths), v0 (frame
                 widths / s), modal_amplitude (a_i, the t = 0 envelope of the modal
                 coordinate q_i of q = Phi^T M x)
        split_rule: "episodes" or "train_fraction"
        params:  every argument of this function

    Args:
        size: output ``(W, H)`` pixels (each >= 16).
        fps: frame rate (Hz, > 0).
        duration_s: length of each recording (s, > 0; at least 8 frames).
        f_modes_hz: ``(f_1, f_2)`` undamped modal frequencies (Hz), ascending.
        zeta: damping ratio of both modes, or ``(zeta_1, zeta_2)``, in ``[0, 1)``.
        masses: ``(m1, m2)`` in kg.
        wall_ratio: ``k3 / k1`` (see :meth:`CoupledCarts.from_modes`).
        amplitude: largest ``|x_j|`` in each recording, frame widths, in
            ``(0, MAX_DISPLACEMENT]``.
        n_episodes: number of recordings (>= 1).
        held_out_episodes: trailing recordings held out, ``1 <= . < n_episodes``
            (used when ``n_episodes > 1``).
        train_fraction: contiguous training share in ``(0, 1)``; used (and
            required) only when ``n_episodes == 1``.
        seed: seeds the initial states (``np.random.default_rng(seed)``) and
            the background texture; the system itself does not depend on it.

    Returns:
        A validated :class:`~lagsplat.io.clip.Clip` with ``episode`` set.

    Raises:
        ValueError: on invalid arguments, an infeasible system (see
            :meth:`CoupledCarts.from_modes`), or a split leaving fewer than 2
            training or 8 held-out frames.
    """
    fps_f, dur = check_timing(fps, duration_s)
    W, H = parse_size(size, 16)
    amp = float(amplitude)
    if not (math.isfinite(amp) and 0.0 < amp <= MAX_DISPLACEMENT):
        raise ValueError(f"amplitude must be in (0, {MAX_DISPLACEMENT}] frame widths, got {amplitude!r}")
    n_ep, n_ho = int(n_episodes), int(held_out_episodes)
    if n_ep != n_episodes or n_ep < 1:
        raise ValueError(f"n_episodes must be an integer >= 1, got {n_episodes!r}")
    if n_ho != held_out_episodes:
        raise ValueError(f"held_out_episodes must be an integer, got {held_out_episodes!r}")
    tf = None
    if train_fraction is not None:
        tf = check_train_fraction(train_fraction)
    T_e = round(dur * fps_f)
    if T_e < 8:
        raise ValueError(f"each episode has {T_e} frames; need at least 8 (increase duration_s or fps)")
    T = n_ep * T_e
    split = np.empty(T, np.int8)
    if n_ep > 1:
        if not (1 <= n_ho < n_ep):
            raise ValueError(
                f"held_out_episodes must be in [1, n_episodes - 1] = [1, {n_ep - 1}], got {held_out_episodes!r}"
            )
        split_rule = "episodes"
        split[: (n_ep - n_ho) * T_e] = TRAIN
        split[(n_ep - n_ho) * T_e :] = HELD_OUT
    else:
        if tf is None:
            raise ValueError("a single episode (n_episodes = 1) needs train_fraction for a contiguous split")
        split_rule = "train_fraction"
        n_train = contiguous_train_frames(tf, T)
        split[:n_train] = TRAIN
        split[n_train:] = HELD_OUT

    system = CoupledCarts.from_modes(f_modes_hz, zeta, masses, wall_ratio)
    rng = np.random.default_rng(int(seed))
    xs, episodes = [], []
    for e in range(n_ep):
        x0, v0, a = _episode_start(system, rng)
        x, _, _ = simulate_coupled_carts(system, x0, v0, fps_f, T_e)
        scale = amp / float(np.max(np.abs(x)))
        xs.append(x * scale)
        episodes.append(
            {
                "frames": [e * T_e, (e + 1) * T_e],
                "x0": [float(v) for v in x0 * scale],
                "v0": [float(v) for v in v0 * scale],
                "modal_amplitude": [float(v) for v in a * scale],
            }
        )
    x_all = np.concatenate(xs)
    images = render_coupled_carts(x_all, size=(W, H), seed=seed)
    t = np.arange(T, dtype=np.float64) / fps_f
    episode = np.repeat(np.arange(n_ep, dtype=np.int16), T_e)

    held = segments(split, HELD_OUT, episode)
    ho = max(held, key=len)
    truth = system.truth()
    truth["f_observed_hz"] = float(spectral_peak_frequency(x_all[ho, 0], 1.0 / fps_f))
    meta: dict[str, Any] = {
        "source": "lagsplat.synth.coupled_carts",
        "truth": truth,
        "x": x_all.tolist(),
        "episodes": episodes,
        "split_rule": split_rule,
        "params": {
            "size": [W, H],
            "fps": fps_f,
            "duration_s": dur,
            "f_modes_hz": [float(v) for v in as_pair(f_modes_hz, "f_modes_hz")],
            "zeta": [float(v) for v in as_pair(zeta, "zeta")],
            "masses": [float(v) for v in as_pair(masses, "masses")],
            "wall_ratio": float(wall_ratio),
            "amplitude": amp,
            "n_episodes": n_ep,
            "held_out_episodes": n_ho,
            "train_fraction": tf,
            "seed": int(seed),
        },
    }
    clip = Clip(images=images, t=t, split=split, meta=meta, episode=episode)
    return clip.validate("lagsplat.synth.coupled_carts")
