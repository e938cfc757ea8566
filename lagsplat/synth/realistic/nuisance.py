"""Nuisance clips: what real footage does that the clip preparation must read or refuse.

Clips of the realistic suite's scenes (:mod:`lagsplat.synth.realistic`) with one nuisance each, on which
automatic preparation (``lagsplat.prepare``: crop, resolution, split, refusals) is measured. Each entry of
:func:`nuisance_clips` carries a ``nuisance`` tag:

* ``distractor``: a person-like figure (legs, a striped shirt, arms, a head; about 1.3 m tall, 0.4 m
  wide) stands at one side of the frame, cut by its border, and sways slowly and irregularly (two
  incommensurate sines at 0.1 to 0.3 Hz, a lean, and one step of about 8 cm), while the pendulum or the
  spring cart oscillates as in the suite. Its image change is larger than the object's.
* ``walk_in``: the same figure, out of view at first, walks in from the edge over the last 20 % of the clip.
* ``sticks``: strong dry friction; the spring cart (or pendulum) swings 3.5 to 4 times and then sticks
  off-centre for the last 40 to 45 % of the 12-s clip (:func:`~lagsplat.synth.realistic.nuisance_motion.sticks_motion`).
* ``short``: a clip of only 2.5 observed periods (its ``duration_s``).
* ``handheld``: filmed by a hand-held phone: a full-shutter motion blur (each frame the mean of
  :data:`HANDHELD_SUBFRAMES` renders spread over its interval) and a slow sway of the whole picture
  (:func:`handheld_sway`: a shift of 2 to 4 % of the frame and a tilt of 1 to 2 degrees, two
  incommensurate sines at 0.15 to 0.35 Hz), so that every pixel moves a little.
* ``shaky``: the same, by a hand that shakes, in a cluttered room (the backdrop renders' clutter wall and
  props): :func:`handheld_tremor` (about 1 % of the frame at 2 to 6 Hz) adds to the sway, and both move
  every sub-frame, so the whole picture blurs by a varying amount from frame to frame (a warp cannot take
  that out: every edge of the scene flickers).
* ``long_string``: a small bob (2.5 cm) on a 1.38-m string hanging from the top of the frame; the bob's
  height moves at twice the swing frequency (0.42 Hz). 128 x 128 and a tall 96 x 160; 20 s long (8.4 periods:
  a 12-s take of 5 periods would be refused as too short before its frequency is used).

Their truth (``<name>.truth.npz``) adds to the suite's keys ``moving_until_s`` (s; the clip's end if it
never stops), ``observed_hz`` (Hz, the frequency over the moving part from the true turning points),
``observed_hz_spectral`` (the spectral peak there) and ``observed_periods``; the distractor clips add
``distractor`` ``[T, 2]``: the figure's sideways shift (m) and lean (rad) per frame.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from lagsplat.io.common import warp_to_reference
from lagsplat.synth.realistic.motion import Motion, one_dof_motion
from lagsplat.synth.realistic.nuisance_motion import long_string_motion, nuisance_truth, short_duration_s, sticks_motion

__all__ = ["nuisance_clips", "nuisance_motion", "nuisance_scene", "distractor_track", "handheld_sway", "handheld_frames", "FIGURE_XML",
           "LONG_STRING", "HANDHELD", "HANDHELD_SUBFRAMES", "handheld_tremor"]  # fmt: skip

HANDHELD_SUBFRAMES = 6
"""Renders averaged into one ``handheld`` frame (a shutter open for the whole frame interval)."""

HANDHELD = ("handheld", "shaky")
"""The nuisances filmed hand-held (:func:`handheld_frames`)."""

LONG_STRING = {"pivot_z": 1.58, "rod": 1.38, "string": 0.003, "bob": 0.025}
"""The long-string pendulum's geometry, m (:func:`~lagsplat.synth.realistic.scene.scene_xml`)."""

FIGURE_XML = """
    <body name="figure" pos="{x0} 0.15 -0.05">
      <joint name="figure_x" type="slide" axis="1 0 0"/>
      <joint name="figure_lean" type="hinge" axis="0 1 0"/>
      <geom type="capsule" fromto="-0.06 0 0.06 -0.06 0 0.5" size="0.055" rgba="0.18 0.2 0.3 1"/>
      <geom type="capsule" fromto="0.06 0 0.06 0.06 0 0.5" size="0.055" rgba="0.18 0.2 0.3 1"/>
      <geom type="capsule" fromto="0 0 0.6 0 0 0.95" size="0.14" material="shirt"/>
      <geom type="capsule" fromto="-0.19 0 1.0 -0.2 0 0.6" size="0.035" material="shirt"/>
      <geom type="capsule" fromto="0.19 0 1.0 0.2 0 0.6" size="0.035" material="shirt"/>
      <geom type="sphere" pos="0 0 1.2" size="0.1" rgba="0.8 0.62 0.5 1"/>
      <geom type="box" pos="0 0 1.29" size="0.09 0.08 0.03" rgba="0.15 0.1 0.08 1"/>
    </body>"""
"""A person-like figure standing on the floor 0.15 m in front of the wall (behind the plane of motion), its
feet at ``{x0}`` (m); joints: a sideways slide (m) and a lean about the feet (rad), the last two of ``qpos``."""

_FIGURE_ASSETS = """
  <asset>
    <texture name="shirt" type="2d" builtin="checker" rgb1="0.8 0.3 0.15" rgb2="0.95 0.85 0.6" width="64" height="64"/>
    <material name="shirt" texture="shirt" texrepeat="2 4"/>
  </asset>"""

_FIGURE_FEET_M = 0.84
"""Distance of the figure's feet from the frame's centre line, m: its outer arm (0.2 m out) crosses the frame's
border (0.855 m out at its depth) however it sways."""

_WALK_IN_FEET_M = (1.35, 0.62)
"""Start (out of view) and end of the walking figure's feet, m from the centre line."""


_CLUTTERED = {"backdrop": "clutter", "scale": 1.0, "mover": None, "moving_light": False}
"""The ``shaky`` entries' scene: the backdrop renders' cluttered wall and props
(:func:`~lagsplat.synth.realistic.backdrops.backdrop_scene`), so that nearly every pixel has an edge to blur."""


def _entry(system: str, nuisance: str, variant: str, seed: int, size: str = "128", effect: str = "none", **extra: Any) -> dict[str, Any]:
    return {"name": f"{system}-{nuisance}-{variant}-{size}", "system": system, "effect": effect, "variant": variant, "size": size,
            "seed": seed, "nuisance": nuisance, **extra}  # fmt: skip


def nuisance_clips() -> list[dict[str, Any]]:
    """The nuisance clips (module docstring): ``{name, system, effect, variant, size, seed, nuisance, ...}``.

    Not part of :func:`~lagsplat.synth.realistic.realistic_suite`; rendered by the Snakemake target
    ``realistic_nuisance``. ``short`` and ``long_string`` entries carry their ``duration_s``; ``sticks`` entries their number of
    half swings and the time they stop by (``half_swings``, ``stop_s``); distractor entries the side of the
    frame the figure stands at (``side``: -1 left, +1 right).
    """
    return [
        _entry("pendulum", "distractor", "s0", 0, side=1),
        _entry("spring_cart", "distractor", "s1", 1, side=-1),
        _entry("pendulum", "walk_in", "s1", 1, side=1),
        _entry("spring_cart", "sticks", "s0", 0, effect="coulomb", half_swings=8, stop_s=7.0),
        _entry("spring_cart", "sticks", "s1", 1, effect="coulomb", half_swings=7, stop_s=6.6),
        _entry("pendulum", "sticks", "s0", 0, effect="coulomb", half_swings=8, stop_s=7.2),
        _entry("pendulum", "short", "s0", 0, periods=2.5, duration_s=short_duration_s("pendulum", 0, 2.5)),
        _entry("spring_cart", "short", "s1", 1, periods=2.5, duration_s=short_duration_s("spring_cart", 1, 2.5)),
        _entry("pendulum", "long_string", "s0", 0, amplitude_deg=22.0, duration_s=20.0),
        _entry("pendulum", "long_string", "s1", 1, size="96x160", amplitude_deg=16.0, duration_s=20.0),
        _entry("pendulum", "handheld", "s0", 0),
        _entry("spring_cart", "handheld", "s1", 1),
        _entry("pendulum", "shaky", "s2", 2, **_CLUTTERED),
        _entry("spring_cart", "shaky", "s0", 0, **_CLUTTERED),
    ]


def _smoothstep(u: np.ndarray) -> np.ndarray:
    u = np.clip(u, 0.0, 1.0)
    return u * u * (3 - 2 * u)


def distractor_track(seed: int, t: np.ndarray, side: int, walk_in: bool = False) -> np.ndarray:
    """The figure's joint positions ``[T, 2]`` at times ``t`` (s): sideways shift (m, from its feet's rest) and lean (rad).

    Shift: ``a1 sin(2 pi f1 t + p1) + a2 sin(2 pi f1 sqrt(3) t + p2)`` (``f1`` 0.1 to 0.13 Hz, ``a`` 3 to 5 cm)
    plus one smooth step of 6 to 9 cm towards the centre over 1.5 s at 4 to 7 s; lean: the same with
    ``f`` 0.14 to 0.17 Hz and 0.17 Hz times the golden ratio, 2 to 4 degrees, tilting towards the step.
    ``walk_in``: out of view (its feet :data:`_WALK_IN_FEET_M` out) until 80 % of the clip, then it walks
    in over 2 s and sways; the step is left out.
    """
    rng = np.random.default_rng([int(seed), 41, 3])
    f1, f2 = rng.uniform(0.1, 0.13), rng.uniform(0.14, 0.17)
    ph = rng.uniform(0, 2 * math.pi, 4)
    a = rng.uniform(0.03, 0.05, 2)
    b = np.radians(rng.uniform(2.0, 4.0, 2))
    step_at, step = rng.uniform(4.0, 7.0), rng.uniform(0.06, 0.09)
    x = a[0] * np.sin(2 * math.pi * f1 * t + ph[0]) + a[1] * np.sin(2 * math.pi * f1 * math.sqrt(3) * t + ph[1])
    lean = b[0] * np.sin(2 * math.pi * f2 * t + ph[2]) + b[1] * np.sin(2 * math.pi * f2 * 1.618034 * t + ph[3])
    if walk_in:
        start, end = _WALK_IN_FEET_M
        x = x + (start - end) * (1 - _smoothstep((t - 0.8 * t[-1]) / 2.0))
    else:
        s = _smoothstep((t - step_at) / 1.5)
        x, lean = x - step * s, lean - 0.6 * step * s  # steps in, leaning in
    return np.stack([side * x, side * lean], 1)


def nuisance_motion(spec: dict[str, Any], fps: float = 30.0, duration_s: float = 12.0) -> Motion:
    """The ground-truth motion of one :func:`nuisance_clips` entry; ``truth`` has ``observed``
    (:func:`~lagsplat.synth.realistic.nuisance_motion.observed`), the distractor entries also its track.

    Raises:
        ValueError: on an unknown ``nuisance`` tag.
    """
    nuisance, system, seed = spec["nuisance"], spec["system"], int(spec["seed"])
    if nuisance in ("distractor", "walk_in", "short") + HANDHELD:
        m = one_dof_motion(system, "none", seed, fps, duration_s)
    elif nuisance == "sticks":
        m = sticks_motion(system, seed, fps, duration_s, int(spec["half_swings"]), float(spec["stop_s"]))
    elif nuisance == "long_string":
        m = long_string_motion(seed, fps, duration_s, LONG_STRING["rod"], float(spec["amplitude_deg"]))
        m.truth["bob_vertical_hz"] = None  # filled below: twice the observed swing frequency
    else:
        raise ValueError(f"unknown nuisance {nuisance!r}; known: distractor, walk_in, sticks, short, long_string, handheld, shaky")
    obs = nuisance_truth(m)
    m.truth.update(obs)
    m.extras = {k: np.float64(v) for k, v in obs.items()}
    if nuisance == "long_string":
        m.truth["bob_vertical_hz"] = 2 * obs["observed_hz"]
    if nuisance in ("distractor", "walk_in"):
        m.extras["distractor"] = distractor_track(seed, m.t, int(spec["side"]), walk_in=nuisance == "walk_in")
    return m


def nuisance_scene(spec: dict[str, Any]) -> dict[str, Any]:
    """Keyword arguments of :func:`~lagsplat.synth.realistic.scene.scene_xml` for the entry's scene (beyond its system)."""
    if spec["nuisance"] == "long_string":
        return {"pendulum": dict(LONG_STRING)}
    if spec["nuisance"] in ("distractor", "walk_in"):
        feet = _WALK_IN_FEET_M[1] if spec["nuisance"] == "walk_in" else _FIGURE_FEET_M
        return {"extra_xml": FIGURE_XML.replace("{x0}", f"{int(spec['side']) * feet:g}"), "extra_assets": _FIGURE_ASSETS}
    return {}


def _sines(key: tuple[int, ...], t: np.ndarray, width: int, height: int, scale: tuple[float, float], tilt_deg: float,
           f_range: tuple[float, float], incommensurate: bool) -> np.ndarray:
    """``[T, 3]`` picture motion (shift x, shift y in px, tilt in rad): per component two sines with
    amplitudes 0.5 to 1 times its unit (``scale`` times the width / height, ``tilt_deg``), random phases and
    frequencies in ``f_range`` (Hz): one frequency ``f`` and ``f sqrt 2`` where ``incommensurate``, else two
    drawn apart. Seeded by ``key``."""
    rng = np.random.default_rng(list(key))
    out = []
    for unit in (scale[0] * width, scale[1] * height, math.radians(tilt_deg)):  # px, px, rad
        f = np.full(2, rng.uniform(*f_range)) if incommensurate else rng.uniform(*f_range, 2)
        ratio = (1.0, math.sqrt(2)) if incommensurate else (1.0, 1.0)
        ph = rng.uniform(0, 2 * math.pi, 2)
        a = rng.uniform(0.5, 1.0, 2) * unit
        out.append(sum(a[k] * np.sin(2 * math.pi * f[k] * ratio[k] * t + ph[k]) for k in range(2)))
    return np.stack(out, 1)


def handheld_sway(seed: int, t: np.ndarray, width: int, height: int) -> np.ndarray:
    """The hand-held camera's picture motion ``[T, 3]`` at times ``t`` (s): shift x, shift y (px) and tilt (rad).

    Each is ``a1 sin(2 pi f t + p1) + a2 sin(2 pi f sqrt(2) t + p2)`` with ``f`` 0.15 to 0.25 Hz; the
    shifts' amplitudes 1 to 2 % of the frame's width / height each (up to about 4 % in all), the tilt's
    0.5 to 1 degree each. Seeded by ``seed``.
    """
    return _sines((int(seed), 53, 7), t, width, height, (0.02, 0.02), 1.0, (0.15, 0.25), incommensurate=True)


def handheld_tremor(seed: int, t: np.ndarray, width: int, height: int) -> np.ndarray:
    """A shaking hand's picture motion ``[T, 3]`` at times ``t`` (s), added to :func:`handheld_sway` for the
    ``shaky`` entries: shift x, shift y (px) and tilt (rad), each two sines at 2 to 6 Hz with amplitudes
    0.3 to 0.6 % of the frame's width / height (up to about 1.2 % in all) and 0.1 to 0.2 degree. Seeded by ``seed``."""
    return _sines((int(seed), 59, 11), t, width, height, (0.006, 0.006), 0.2, (2.0, 6.0), incommensurate=False)


def _move(frame: np.ndarray, dx: float, dy: float, tilt: float) -> np.ndarray:
    """``frame [h, w, 3]`` shifted by ``(dx, dy)`` px and tilted by ``tilt`` rad about its centre
    (:func:`lagsplat.io.common.warp_to_reference`: bilinear, edges replicated)."""
    import cv2

    h, w = frame.shape[:2]
    A = cv2.getRotationMatrix2D(((w - 1) / 2, (h - 1) / 2), math.degrees(tilt), 1.0)
    A[:, 2] += (dx, dy)
    return warp_to_reference(frame, A)


def handheld_frames(spec: dict[str, Any], width: int, height: int, fps: float, duration_s: float, render) -> np.ndarray:
    """A ``handheld`` or ``shaky`` entry's frames ``[T, height, width, 3]`` uint8: the motion rendered at
    :data:`HANDHELD_SUBFRAMES` times the frame rate by ``render(q)`` (uint8 frames of ``q [T', d]``),
    each frame the mean of the renders over its interval. ``handheld``: the mean is then shifted and tilted
    about the centre by :func:`handheld_sway` (edges replicated, as a stabiliser would leave them);
    ``shaky``: every render is moved by the sway plus :func:`handheld_tremor` at its own time before the mean."""
    n = HANDHELD_SUBFRAMES
    fine = nuisance_motion(spec, fps * n, duration_s)
    sub = render(fine.q).astype(np.float32)
    T = len(sub) // n
    seed = int(spec["seed"])
    if spec["nuisance"] == "shaky":
        tf = np.arange(T * n) / (fps * n)
        moves = handheld_sway(seed, tf, width, height) + handheld_tremor(seed, tf, width, height)
        sub = np.stack([_move(f, *mv) for f, mv in zip(sub[: T * n], moves)])
        return np.clip(sub.reshape(T, n, height, width, 3).mean(1) + 0.5, 0, 255).astype(np.uint8)
    frames = sub[: T * n].reshape(T, n, height, width, 3).mean(1)
    sway = handheld_sway(seed, np.arange(T) / fps, width, height)
    return np.stack([np.clip(_move(f, *mv) + 0.5, 0, 255).astype(np.uint8) for f, mv in zip(frames, sway)])
