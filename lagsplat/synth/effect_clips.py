"""Clips of the effect library: pictures of the pendulum and the cart with their one unmodelled effect, the clip writer and the blind suite's list (:mod:`lagsplat.synth.effects` simulates the motion)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from lagsplat.io.clip import Clip
from lagsplat.synth._render import (
    SUPERSAMPLE,
    Canvas,
    background,
    over,
    parse_size,
    render_frames,
)
from lagsplat.synth.coupled_carts import CART_HEIGHT, CART_WIDTH
from lagsplat.synth.coupled_carts_clip import render_coupled_carts
from lagsplat.synth.effect_truth import EFFECTS, SYSTEMS, check_label
from lagsplat.synth.effects import EffectRun, simulate_effect
from lagsplat.synth.pendulum import BOB_RADIUS, PIVOT_Y, ROD_LENGTH

__all__ = ["render_effect", "make_effect_clip", "blind_suite"]

# pictures, in units of the frame height H
BOB_LEFT_RGB = (0.85, 0.20, 0.15)
BOB_RIGHT_RGB = (0.15, 0.35, 0.85)
BUMPER_RGB = (0.10, 0.55, 0.25)
CART_RAIL_Y = 0.62  # single cart rail height, units of H
CART_RGB = (0.86, 0.16, 0.12)
OUTLINE_RGB = (0.12, 0.12, 0.14)
PIVOT_RADIUS = 0.03
PIVOT_RGB = (0.15, 0.15, 0.17)
RAIL_RGB = (0.35, 0.35, 0.37)
ROD_HALF_WIDTH = 0.018
ROD_RGB = (0.25, 0.25, 0.28)
SLIDER_RGB = (0.30, 0.30, 0.34)
WALL_RGB = (0.45, 0.42, 0.38)
WHEEL_RGB = (0.20, 0.20, 0.22)



# ---------------------------------------------------------------------- pictures
def _pendulum_fg(theta: float, pivot_dx: float, W: int, H: int, s: int, slider: bool) -> np.ndarray:
    """Pendulum at ``theta`` (rad) with the pivot shifted by ``pivot_dx`` (pixels); premultiplied RGBA."""
    cv = Canvas(W, H, s)
    px, py = W / 2.0 + pivot_dx, PIVOT_Y * H
    if slider:
        cv.rect(px - 0.07 * H, py - 0.05 * H, px + 0.07 * H, py + 0.05 * H, SLIDER_RGB)
    ux, uy = math.sin(theta), math.cos(theta)
    L, r, hw = ROD_LENGTH * H, BOB_RADIUS * H, ROD_HALF_WIDTH * H
    bx, by = px + L * ux, py + L * uy
    nx, ny = uy, -ux
    cv.convex([(px + hw * nx, py + hw * ny), (bx + hw * nx, by + hw * ny), (bx - hw * nx, by - hw * ny), (px - hw * nx, py - hw * ny)], ROD_RGB)
    cv.disc(px, py, PIVOT_RADIUS * H, PIVOT_RGB)
    cv.disc(bx, by, r, BOB_LEFT_RGB)
    phi = math.degrees(math.atan2(uy, ux))
    cv.sector(bx, by, r, phi - 180.0, phi, BOB_RIGHT_RGB)
    return cv.reduce(W, H)


def _pendulum_backdrop(W: int, H: int, s: int, seed: int, stop: float | None, side: float, rail: bool) -> np.ndarray:
    cv = Canvas(W, H, s)
    if rail:
        cv.rect(0.1 * W, PIVOT_Y * H - 0.012 * H, 0.9 * W, PIVOT_Y * H + 0.012 * H, RAIL_RGB)
    if stop is not None:  # a post the bob's edge touches at theta = stop
        L, r = ROD_LENGTH * H, BOB_RADIUS * H
        cx = W / 2.0 + L * math.sin(stop) + side * r
        cy = PIVOT_Y * H + L * math.cos(stop)
        cv.rect(cx, cy - 0.12 * H, cx + side * 0.05 * W, cy + 0.12 * H, BUMPER_RGB)
    return np.clip(over(cv.reduce(W, H), background(W, H, seed)), 0.0, 1.0)


def _cart_fg(x: float, W: int, H: int, s: int) -> np.ndarray:
    """One cart (style of :mod:`~lagsplat.synth.coupled_carts`) at displacement ``x`` frame widths."""
    cv = Canvas(W, H, s)
    hw, bh, ol = 0.5 * CART_WIDTH * W, CART_HEIGHT * H, 0.025 * H
    cx, y = (0.5 + float(x)) * W, CART_RAIL_Y * H
    wr = 0.045 * H
    for sgn in (-1.0, 1.0):
        cv.disc(cx + sgn * 0.27 * 2.0 * hw, y - wr, wr, WHEEL_RGB)
    top, bottom = y - 0.06 * H - bh, y - 0.06 * H
    cv.rect(cx - hw, top, cx + hw, bottom, OUTLINE_RGB)
    cv.rect(cx - hw + ol, top + ol, cx + hw - ol, bottom - ol, CART_RGB)
    return cv.reduce(W, H)


def _cart_backdrop(W: int, H: int, s: int, seed: int, stop: float | None, side: float) -> np.ndarray:
    cv = Canvas(W, H, s)
    ww, y = 0.035 * W, CART_RAIL_Y * H
    cv.rect(ww, y, W - ww, y + 0.025 * H, RAIL_RGB)
    cv.rect(0.0, y - 0.27 * H, ww, y + 0.025 * H, WALL_RGB)
    cv.rect(W - ww, y - 0.27 * H, W, y + 0.025 * H, WALL_RGB)
    if stop is not None:  # a bumper the cart's side touches at x = stop
        cx = (0.5 + stop) * W + side * 0.5 * CART_WIDTH * W
        cv.rect(cx, y - 0.2 * H, cx + side * 0.04 * W, y, BUMPER_RGB)
    return np.clip(over(cv.reduce(W, H), background(W, H, seed)), 0.0, 1.0)


def render_effect(run: EffectRun, size: Sequence[int] = (64, 64), seed: int = 0, supersample: int = SUPERSAMPLE) -> np.ndarray:
    """Render an :class:`EffectRun` as uint8 ``[T,H,W,3]`` RGB frames.

    The end stop is drawn as a static green bumper; the missing DOF as a
    moving pivot slider (pendulum) or a second cart (cart, drawn by
    :func:`~lagsplat.synth.coupled_carts_clip.render_coupled_carts`).

    Raises:
        ValueError: on a bad ``size`` or ``supersample``.
    """
    W, H = parse_size(size, 16)
    s = int(supersample)
    if s < 1:
        raise ValueError(f"supersample must be >= 1, got {supersample!r}")
    p = run.truth["effect_params"]
    stop = p.get("x_stop") if run.effect == "end_stop" else None
    side = float(p.get("side", 1.0))
    if run.system == "cart" and run.effect == "missing_dof":
        return render_coupled_carts(np.stack([run.x, run.second], 1), size=(W, H), seed=seed, supersample=s)
    if run.system == "cart":
        back = _cart_backdrop(W, H, s, seed, stop, side)
        return render_frames(run.x, lambda xi: _cart_fg(float(xi), W, H, s), back)
    moving = run.effect == "missing_dof"
    back = _pendulum_backdrop(W, H, s, seed, stop, side, rail=moving)
    L = ROD_LENGTH * H
    states = np.stack([run.x, run.second * L], 1)
    return render_frames(states, lambda st: _pendulum_fg(float(st[0]), float(st[1]), W, H, s, moving), back)


def make_effect_clip(
    system: str = "pendulum",
    effect: str = "none",
    seed: int = 0,
    actuated: bool | None = None,
    size: Sequence[int] = (64, 64),
    fps: float = 30.0,
    duration_s: float = 15.0,
    n_episodes: int = 4,
    held_out_episodes: int = 1,
) -> Clip:
    """A rendered clip of a simple system with one known effect (the blind-suite clip).

    Arguments as :func:`simulate_effect`, plus ``size`` (``(W, H)`` pixels).
    ``seed`` also seeds the background texture.

    ``meta`` holds ``source`` (``"lagsplat.synth.effects"``), ``label`` (the
    effect), ``system``, ``truth`` (:func:`sample_truth`, completed),
    ``latent`` (per-frame 1-D coordinate), ``second`` (the missing DOF, or
    zeros) and ``params`` (every argument).

    Returns:
        A validated :class:`~lagsplat.io.clip.Clip` with ``episode`` and, when
        actuated, one actuation channel ``"u1"``.

    Raises:
        ValueError: as :func:`simulate_effect`.
    """
    run = simulate_effect(system, effect, seed, actuated, fps, duration_s, n_episodes, held_out_episodes)
    W, H = parse_size(size, 16)
    images = render_effect(run, (W, H), seed)
    meta = {
        "source": "lagsplat.synth.effects",
        "label": effect,
        "system": system,
        "truth": run.truth,
        "latent": [float(v) for v in run.latent],
        "second": [float(v) for v in run.second],
        "params": {
            "system": system, "effect": effect, "seed": int(seed), "actuated": run.truth["actuated"], "size": [W, H],
            "fps": float(fps), "duration_s": float(duration_s), "n_episodes": int(n_episodes),
            "held_out_episodes": int(held_out_episodes),
        },
    }  # fmt: skip
    u_names = ["u1"] if run.u.shape[1] else []
    clip = Clip(images=images, t=run.t, u=run.u, u_names=u_names, split=run.split, meta=meta, episode=run.episode)
    return clip.validate("lagsplat.synth.effects")


def blind_suite(n_per_effect: int = 2, systems: Sequence[str] = SYSTEMS, actuated_controls: bool = True) -> list[dict[str, Any]]:
    """The blind benchmark suite: ``n_per_effect`` clips per (system, effect), controls included.

    Every effect on every system (``actuation_delay`` on actuated clips), and,
    with ``actuated_controls``, ``n_per_effect`` actuated clips without effect
    per system, so that a delay is never found where there is none.

    Returns:
        ``[{"name", "system", "effect", "seed", "actuated"}]``, each entry the
        keyword arguments of :func:`make_effect_clip` / :func:`simulate_effect` plus a ``name``.

    Raises:
        ValueError: if ``n_per_effect < 1`` or a system is unknown.
    """
    if int(n_per_effect) < 1:
        raise ValueError(f"n_per_effect must be >= 1, got {n_per_effect!r}")
    out = []
    for system in systems:
        check_label(system, "none")
        for effect in EFFECTS:
            for seed in range(int(n_per_effect)):
                act = effect == "actuation_delay"
                out.append({"name": f"{system}-{effect}-{seed}", "system": system, "effect": effect, "seed": seed, "actuated": act})
        if actuated_controls:
            for seed in range(int(n_per_effect)):
                out.append({"name": f"{system}-none_actuated-{seed}", "system": system, "effect": "none", "seed": 100 + seed, "actuated": True})
    return out
