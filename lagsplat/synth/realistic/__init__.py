"""A realistic test suite rendered by an independent renderer (MuJoCo), with ground truth.

The project's own procedural clips (:mod:`lagsplat.synth`) are drawn by its own
2-D painters on plain backgrounds; a chart that holds on them may not hold on
video. These clips are rendered by MuJoCo (:mod:`lagsplat.synth.realistic.scene`)
with what real video has: a textured backdrop and floor, static distractors,
a shadow-casting light (the shadow moves with the object), a dim fill light and
a vignette (a lighting gradient), sensor noise and MP4 compression; the object
covers a few percent of the frame.

Systems: ``pendulum``, ``spring_cart``, ``torsion_disk`` (rotation about the
camera axis, released at 60 or 120 degrees) and the 2-DOF ``double_pendulum``.
The 1-DOF systems carry no effect or one effect of the diagnosis library
(:mod:`lagsplat.synth.effects`; ``actuation_delay`` is left out: it needs a
logged input, and the disk has no second body for ``missing_dof``).

Each clip is ``<name>.mp4`` with ``<name>.truth.npz`` beside it: per-frame ``t``,
``q``, ``qdot`` and the hidden acceleration, ``f0_hz``, and the parameters as
JSON (:func:`make_clip`). :func:`realistic_suite` lists the clips; the
command line (``python -m lagsplat.synth.realistic --list`` / ``--clip NAME
--out DIR``) builds one; the Snakemake target ``realistic_suite`` builds all.
:func:`nuisance_clips` lists clips with one nuisance of real footage each (a
moving distractor, a motion that stops, a clip too short, a long string;
:mod:`lagsplat.synth.realistic.nuisance`), built by the same :func:`make_clip`
and the Snakemake target ``realistic_nuisance``. :func:`backdrop_clips` lists the suite's oscillators in front of
other backdrops, with other distractors and at other sizes (:mod:`lagsplat.synth.realistic.backdrops`; the
Snakemake target ``realistic_backdrops``). :func:`impact_clips` lists impact oscillators: the 1-DOF systems
bouncing off rigid stops with a coefficient of restitution below 1 (:mod:`lagsplat.synth.realistic.impacts`; the
Snakemake target ``realistic_impacts``).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from lagsplat.synth.effect_truth import EFFECTS
from lagsplat.synth.realistic.backdrops import backdrop_clips, backdrop_motion, backdrop_scene
from lagsplat.synth.realistic.camera import add_camera_nuisances, render_frames, write_mp4
from lagsplat.synth.realistic.impacts import impact_clips, impact_motion, impact_scene
from lagsplat.synth.realistic.motion import Motion, double_pendulum_motion, one_dof_motion, slide_out_motion, spin_down_motion
from lagsplat.synth.realistic.nuisance import HANDHELD, handheld_frames, nuisance_clips, nuisance_motion, nuisance_scene
from lagsplat.synth.realistic.scene import scene_xml

__all__ = ["realistic_suite", "outside_class_clips", "nuisance_clips", "backdrop_clips", "impact_clips", "clip_spec", "make_clip", "motion_of", "SIZES"]

SIZES = {"128": (128, 128), "640x480": (640, 480), "96x160": (96, 160), "160x96": (160, 96)}
"""Resolutions, name -> (width, height)."""

_ONE_DOF = ("pendulum", "spring_cart", "torsion_disk")


def _effects(system: str) -> list[str]:
    return [e for e in EFFECTS if e != "actuation_delay" and not (system == "torsion_disk" and e == "missing_dof")]


def realistic_suite() -> list[dict[str, Any]]:
    """Every clip of the suite: ``{name, system, effect, variant, size, seed}``.

    At 128 x 128: each 1-DOF system with no effect and each effect, two variants each
    (pendulum and spring cart: two seeds, i.e. two draws of the parameters and the
    release; torsion disk: released at 60 and at 120 degrees), and the double pendulum
    released at 15 and at 30 degrees. At 640 x 480: one clip per system, no effect.
    """
    out = []
    for system in _ONE_DOF:
        for effect in _effects(system):
            for k in (0, 1):
                variant = ("a60", "a120")[k] if system == "torsion_disk" else f"s{k}"
                out.append({"name": f"{system}-{effect}-{variant}-128", "system": system, "effect": effect, "variant": variant, "size": "128", "seed": k})
    for k, amp in enumerate((15, 30)):
        out.append({"name": f"double_pendulum-none-a{amp}-128", "system": "double_pendulum", "effect": "none", "variant": f"a{amp}", "size": "128", "seed": k})
    for system, variant in (("pendulum", "s0"), ("spring_cart", "s0"), ("torsion_disk", "a120"), ("double_pendulum", "a30")):
        out.append({"name": f"{system}-none-{variant}-640x480", "system": system, "effect": "none", "variant": variant, "size": "640x480", "seed": 0})
    return out


def outside_class_clips() -> list[dict[str, Any]]:
    """Clips of motions outside the model class, which the pipeline must name and stop on, not fit.

    A disk spinning down (``torsion_disk-spin_down-s0-128``: a rotation of a few turns, no rest
    state it oscillates about) and a cart pushed out of view (``spring_cart-slide_out-s0-128``).
    Each entry's ``outside_class`` says which (``rotation``, ``leaves_frame``). They are not
    part of :func:`realistic_suite` (no frequency to score); ``realistic_suite`` (the Snakemake
    target) renders them too.
    """
    return [
        {"name": "torsion_disk-spin_down-s0-128", "system": "torsion_disk", "effect": "spin_down", "variant": "s0", "size": "128", "seed": 0,
         "outside_class": "rotation"},
        {"name": "spring_cart-slide_out-s0-128", "system": "spring_cart", "effect": "slide_out", "variant": "s0", "size": "128", "seed": 0,
         "outside_class": "leaves_frame"},
    ]  # fmt: skip


def clip_spec(name: str) -> dict[str, Any]:
    """The entry called ``name`` (:func:`realistic_suite`, :func:`outside_class_clips`, :func:`nuisance_clips`, :func:`backdrop_clips`
    or :func:`impact_clips`).

    Raises:
        KeyError: naming the unknown clip and how to list the known ones.
    """
    for e in realistic_suite() + outside_class_clips() + nuisance_clips() + backdrop_clips() + impact_clips():
        if e["name"] == name:
            return e
    raise KeyError(f"unknown realistic clip {name!r} (python -m lagsplat.synth.realistic --list, --list-nuisance, --list-backdrops, --list-impacts)")


def motion_of(spec: dict[str, Any], fps: float = 30.0, duration_s: float = 12.0) -> Motion:
    """The ground-truth motion of one entry (:mod:`lagsplat.synth.realistic.motion`; a nuisance clip's:
    :func:`lagsplat.synth.realistic.nuisance.nuisance_motion`; a backdrop clip's: :func:`~lagsplat.synth.realistic.backdrops.backdrop_motion`;
    an impact clip's: :func:`~lagsplat.synth.realistic.impacts.impact_motion`)."""
    system, variant = spec["system"], spec["variant"]
    if "nuisance" in spec:
        return nuisance_motion(spec, fps, duration_s)
    if "backdrop" in spec:
        return backdrop_motion(spec, fps, duration_s)
    if spec.get("kind") == "impact":
        return impact_motion(spec, fps, duration_s)
    if spec["effect"] == "spin_down":
        return spin_down_motion(spec["seed"], fps, duration_s)
    if spec["effect"] == "slide_out":
        return slide_out_motion(spec["seed"], fps, duration_s)
    if system == "double_pendulum":
        return double_pendulum_motion(spec["seed"], fps, duration_s, float(variant[1:]))
    amp = float(variant[1:]) if system == "torsion_disk" else 60.0
    return one_dof_motion(system, spec["effect"], int(spec["seed"]), fps, duration_s, amplitude_deg=amp)


def make_clip(
    name: str, out_dir: str | Path, fps: float = 30.0, duration_s: float | None = None, size: tuple[int, int] | None = None, noise_std: float = 3.0
) -> Path:
    """Render clip ``name`` to ``<out_dir>/<name>.mp4`` with ``<name>.truth.npz`` beside it (both atomically).

    Args:
        fps, duration_s: frame rate (Hz) and length (s); the length defaults to the entry's ``duration_s``
            (the ``short`` nuisance clips), else 12 s.
        size: ``(width, height)`` override (tests); default the entry's resolution.
        noise_std: sensor noise, grey levels.

    Returns:
        The path of the MP4.
    """
    spec = clip_spec(name)
    duration_s = float(spec.get("duration_s", 12.0)) if duration_s is None else duration_s
    m = motion_of(spec, fps, duration_s)
    W, H = size or SIZES[spec["size"]]
    if spec.get("nuisance") in HANDHELD:
        xml = backdrop_scene(spec, half_w=0.8 * W / H) if "backdrop" in spec else None
        clean = handheld_frames(spec, W, H, fps, duration_s, lambda q: render_frames(spec["system"], q, W, H, xml=xml))
    elif "nuisance" in spec:
        scene = scene_xml(spec["system"], distance_m=2.2, **nuisance_scene(spec))
        clean = render_frames(spec["system"], m.q, W, H, xml=scene, extra_qpos=m.extras.get("distractor"))
    elif "backdrop" in spec:
        scene = backdrop_scene(spec, half_w=0.8 * W / H)
        clean = render_frames(spec["system"], m.q, W, H, xml=scene, extra_qpos=m.extras.get("backdrop_qpos"))
    elif spec.get("kind") == "impact":
        clean = render_frames(spec["system"], m.q, W, H, xml=impact_scene(spec))
    else:
        clean = render_frames(spec["system"], m.q, W, H)
    frames = add_camera_nuisances(clean, noise_std, seed=int(spec["seed"]) + 17)
    out = Path(out_dir)
    mp4 = write_mp4(frames, out / f"{name}.mp4", fps)
    truth = {**m.truth, **spec, "fps": fps, "duration_s": duration_s, "width": W, "height": H, "noise_std": noise_std}
    tmp = out / f".{name}.truth.tmp{os.getpid()}.npz"
    with open(tmp, "wb") as fh:
        np.savez(fh, t=m.t, q=m.q, qdot=m.qdot, hidden=m.hidden, f0_hz=np.float64(m.f0_hz), truth_json=np.array(json.dumps(truth, default=float)), **m.extras)
    os.replace(tmp, out / f"{name}.truth.npz")
    return mp4
