"""Backdrop clips: the realistic suite's oscillators in front of other walls, other distractors, at other sizes.

A held-out set for Stage 1 (the autoencoder): the motions are the suite's own (same system, effect, seed and
release as the suite clip named in each entry's ``twin``; :func:`~lagsplat.synth.realistic.motion.one_dof_motion`),
the room is changed (the suite's crate, bottle and second cart are taken out; :func:`backdrop_scene`):

* ``backdrop``: ``checker`` (black and white squares of :data:`CHECKER_M`), ``wood`` (planks with rings and
  streaks, :func:`wood_texture`), a photograph shipped with scikit-image (``skimage.data``; licences as its
  docstrings give them: ``coffee``, CC0, Rachel Michetti / Pikolo Espresso Bar; ``chelsea``, CC0, Stefan van
  der Walt; ``astronaut``, NASA, public domain; ``rocket``, SpaceX, public domain; ``ihc``:
  ``immunohistochemistry``, CMMI, "no known copyright restrictions"), or ``clutter`` (a plain sage-green wall with
  :data:`CLUTTER_N` coloured boxes, spheres and cylinders on it);
* static props: 2 to 5 coloured shapes in front of the object (foreground) and behind it, kept off the
  object's swept area (seeded, :func:`props_xml`);
* ``mover``: a slowly turning three-bladed fan (blades pass at :data:`FAN_RATIO` times the object's ``f0``,
  whose harmonics miss ``f0`` by 18 % or more) or a plant swaying (two incommensurate sines at :data:`PLANT_RATIO` and ``sqrt 2`` times it of ``f0``,
  4 to 7 degrees each);
* ``moving_light``: the shadow-casting key light slides sideways (0.05 Hz, 0.6 m), so shadows move;
* ``scale``: the object's size over the suite's (0.5 to 2; pendulum rod and bob, cart, disk);
* ``size``: 128 x 128, a wide 160 x 96 or a tall 96 x 160 (the vertical field is always 1.6 m).

Textures (the wood and the photographs) are written as PNG files to :func:`texture_dir` and loaded by the MJCF.
The truth file has the suite's keys, plus ``backdrop_qpos`` ``[T, k]`` (the mover's angle, rad, then the
light's shift, m) when something moves besides the object. Units: metres, radians, Hz.
"""

from __future__ import annotations

import colorsys
import hashlib
import math
import os
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from lagsplat.synth.realistic.motion import Motion, one_dof_motion
from lagsplat.synth.realistic.scene import ROD_M, scene_xml

__all__ = ["backdrop_clips", "backdrop_motion", "backdrop_scene", "wood_texture", "props_xml", "texture_dir", "PHOTOS", "FAN_RATIO", "PLANT_RATIO"]

PHOTOS = {"coffee": "coffee", "chelsea": "chelsea", "astronaut": "astronaut", "rocket": "rocket", "ihc": "immunohistochemistry"}
"""Photograph backdrops: name -> ``skimage.data`` function (licences: module docstring)."""

CHECKER_M = 0.07
"""Side of one checker square on the wall, m (about 5 pixels at 128 x 128)."""

CLUTTER_N = 42
"""Number of coloured objects on the ``clutter`` wall."""

FAN_RATIO = 0.41
"""Blade-passing frequency of the fan over the object's ``f0`` (harmonics 0.41, 0.82, 1.23, ... of ``f0``)."""

PLANT_RATIO = 0.2
"""The plant's slower sway frequency over the object's ``f0``; the other is ``sqrt 2`` times it (0.2 and 0.28 ``f0``:
their harmonics up to the third miss ``f0`` by 15 % or more)."""

_CAM_Y, _WALL_Y = 2.2, 0.35
"""Camera distance from the plane of motion, and the wall's depth behind it, m."""

_COLOUR = {"pendulum": 0.02, "spring_cart": 0.62, "torsion_disk": 0.0}
"""Hue of the object's main colour (bob, cart body, disk's dot); the clutter keeps 0.07 away from it."""


def _entry(system: str, backdrop: str, variant: str, seed: int, scale: float, size: str = "128", effect: str = "none", **extra: Any) -> dict[str, Any]:
    tag = f"bd_{backdrop}" + ("" if effect == "none" else f"-{effect}")
    twin = f"{system}-{effect}-{variant}-128"
    return {"name": f"{system}-{tag}-{variant}-{size}", "system": system, "effect": effect, "variant": variant, "size": size, "seed": seed,
            "backdrop": backdrop, "scale": scale, "mover": extra.pop("mover", None), "moving_light": extra.pop("moving_light", False),
            "twin": twin, **extra}  # fmt: skip


def backdrop_clips() -> list[dict[str, Any]]:
    """The backdrop clips (module docstring): ``{name, system, effect, variant, size, seed, backdrop, scale, mover,
    moving_light, twin}``; a mover's place (``mover_at``: ``[x, z]``, m, in the plane of motion) with it.

    Not part of :func:`~lagsplat.synth.realistic.realistic_suite`; rendered by the Snakemake target ``realistic_backdrops``.
    """
    return [
        _entry("pendulum", "checker", "s0", 0, 1.0),
        _entry("spring_cart", "checker", "s1", 1, 1.75, size="160x96"),
        _entry("torsion_disk", "wood", "a120", 1, 0.5, effect="coulomb"),
        _entry("pendulum", "wood", "s1", 1, 1.5, size="96x160", moving_light=True),
        _entry("spring_cart", "coffee", "s0", 0, 1.0, mover="fan", mover_at=[0.5, 1.3]),
        _entry("spring_cart", "chelsea", "s1", 1, 0.5, effect="quadratic_drag"),
        _entry("torsion_disk", "astronaut", "a60", 0, 1.75, moving_light=True),
        _entry("pendulum", "rocket", "s1", 1, 0.5),
        _entry("pendulum", "ihc", "s0", 0, 1.75, mover="fan", mover_at=[0.55, 0.36]),
        _entry("spring_cart", "clutter", "s0", 0, 2.0),
        _entry("torsion_disk", "clutter", "a120", 1, 1.0, mover="plant", mover_at=[-0.58, 0.1]),
        _entry("pendulum", "clutter", "s1", 1, 1.0, effect="coulomb"),
    ]


def backdrop_motion(spec: dict[str, Any], fps: float = 30.0, duration_s: float = 12.0) -> Motion:
    """The entry's motion: its suite twin's (same law, seed and release), with ``extras["backdrop_qpos"] [T, k]``
    when a mover or the light moves, and their frequencies in ``truth`` (``mover_hz``, ``light_hz``)."""
    system = spec["system"]
    amp = float(spec["variant"][1:]) if system == "torsion_disk" else 60.0
    m = one_dof_motion(system, spec["effect"], int(spec["seed"]), fps, duration_s, amplitude_deg=amp)
    rng = np.random.default_rng([int(spec["seed"]), 59, sum(map(ord, spec["name"]))])
    cols = []
    if spec["mover"] == "fan":  # three blades: the image repeats every third of a turn
        f_blade = FAN_RATIO * m.f0_hz
        cols.append(2 * math.pi * f_blade / 3 * m.t + rng.uniform(0, 2 * math.pi))
        m.truth["mover_hz"] = [f_blade]
    elif spec["mover"] == "plant":
        f1 = PLANT_RATIO * m.f0_hz
        f2, a, ph = f1 * math.sqrt(2.0), np.radians(rng.uniform(4.0, 7.0, 2)), rng.uniform(0, 2 * math.pi, 2)
        cols.append(a[0] * np.sin(2 * math.pi * f1 * m.t + ph[0]) + a[1] * np.sin(2 * math.pi * f2 * m.t + ph[1]))
        m.truth["mover_hz"] = [f1, f2]
    if spec["moving_light"]:
        cols.append(0.6 * np.sin(2 * math.pi * 0.05 * m.t + rng.uniform(0, 2 * math.pi)))
        m.truth["light_hz"] = 0.05
    if cols:
        m.extras = {**m.extras, "backdrop_qpos": np.stack(cols, 1)}
    return m


def texture_dir() -> Path:
    """Folder of the generated texture PNGs: ``$LAGSPLAT_TEXTURE_DIR``, else ``<tmp>/lagsplat-backdrop-textures``."""
    return Path(os.environ.get("LAGSPLAT_TEXTURE_DIR") or Path(tempfile.gettempdir()) / "lagsplat-backdrop-textures")


def _png(name: str, rgb: np.ndarray) -> str:
    """Write ``rgb [H, W, 3]`` uint8 as ``<texture_dir>/<name>-<hash>.png`` (atomically, once); its absolute path."""
    ok, buf = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    if not ok:
        raise OSError(f"cannot encode texture {name}")
    path = texture_dir() / f"{name}-{hashlib.sha1(buf.tobytes()).hexdigest()[:12]}.png"
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.stem}.tmp{os.getpid()}.png")
        tmp.write_bytes(buf.tobytes())
        os.replace(tmp, path)
    return str(path.resolve())


def _smooth_noise(rng: np.random.Generator, shape: tuple[int, int], modes: int, max_freq: float) -> np.ndarray:
    """A sum of ``modes`` random plane waves (frequencies up to ``max_freq`` cycles per image), ``[H, W]``, std about 1."""
    H, W = shape
    yy, xx = np.mgrid[0:H, 0:W] / np.array([H, W])[:, None, None]
    k = rng.uniform(-max_freq, max_freq, (modes, 2))
    ph = rng.uniform(0, 2 * math.pi, modes)
    return sum(np.cos(2 * math.pi * (k[i, 0] * yy + k[i, 1] * xx) + ph[i]) for i in range(modes)) * math.sqrt(2.0 / modes)


def wood_texture(seed: int, size: int = 512, planks: int = 4) -> np.ndarray:
    """A procedural wood-grain texture ``[size, size, 3]`` uint8: ``planks`` vertical planks, each cut across the
    rings of a log (ring distance from a centre far to one side, warped by smooth noise) with fine streaks along
    the grain and a dark seam between planks."""
    rng = np.random.default_rng([int(seed), 61])
    yy, xx = np.mgrid[0:size, 0:size] / size
    out = np.zeros((size, size, 3))
    light, dark = np.array([0.80, 0.60, 0.38]), np.array([0.46, 0.28, 0.14])
    w = 1.0 / planks
    for p in range(planks):
        cx, cy = (p + 0.5) * w + rng.uniform(-0.3, 0.3), rng.uniform(-2.0, 3.0)
        warp = 0.012 * _smooth_noise(rng, (size, size), 6, 3.0)
        r = np.sqrt(((xx - cx) * 4.0) ** 2 + (0.15 * (yy - cy)) ** 2) + warp
        ring = 0.5 + 0.5 * np.sin(2 * math.pi * r * rng.uniform(9, 14)) ** 3
        streak = 0.06 * np.cos(2 * math.pi * (xx * rng.uniform(90, 140) + 0.3 * _smooth_noise(rng, (size, size), 4, 2.0)))
        tone = np.clip(ring + streak, 0, 1)[..., None] * rng.uniform(0.85, 1.0)
        mask = (xx >= p * w) & (xx < (p + 1) * w)
        out[mask] = (dark + (light - dark) * tone)[mask]
    seam = np.abs(((xx * planks) + 0.5) % 1.0 - 0.5) < 0.006 * planks
    out[seam] *= 0.35
    return (np.clip(out, 0, 1) * 255 + 0.5).astype(np.uint8)


def _photo(name: str, aspect: float) -> np.ndarray:
    """The ``skimage.data`` photograph, centre-cropped to width / height ``aspect``, RGB uint8."""
    from skimage import data

    img = np.asarray(getattr(data, PHOTOS[name])())
    H, W = img.shape[:2]
    if W / H > aspect:
        w = int(round(H * aspect))
        img = img[:, (W - w) // 2 : (W - w) // 2 + w]
    else:
        h = int(round(W / aspect))
        img = img[(H - h) // 2 : (H - h) // 2 + h]
    return np.ascontiguousarray(img[..., :3])


def _world(xp: float, zp: float, y: float) -> tuple[float, float]:
    """The ``(x, z)`` at depth ``y`` (m, + away from the camera) that the camera sees where it sees ``(xp, zp)`` of the plane of motion."""
    k = (_CAM_Y + y) / _CAM_Y
    return xp * k, 0.85 + (zp - 0.85) * k


def _keep_out(system: str, s: float) -> tuple[float, float, float, float]:
    """The object's swept area in the plane of motion, ``(x0, x1, z0, z1)``, m, with a 5-cm margin."""
    if system == "pendulum":
        rod, pivot = ROD_M * s, _pivot_z(s)
        r = rod * 0.36 + 0.06 * s + 0.05
        return -r, r, pivot - rod - 0.06 * s - 0.05, pivot + 0.05
    if system == "spring_cart":
        return -0.8, 0.8, 0.42, 0.56 + 0.1 * s + 0.05
    r = 0.2 * s + 0.06
    return -r, r, 0.85 - r, 0.85 + r


def _pivot_z(s: float) -> float:
    return 0.9 + 0.8 * ROD_M * s


def _rgba(h: float, rng: np.random.Generator) -> str:
    r, g, b = colorsys.hsv_to_rgb(h % 1.0, rng.uniform(0.55, 1.0), rng.uniform(0.55, 1.0))
    return f"{r:.3f} {g:.3f} {b:.3f} 1"


def _shape(rng: np.random.Generator, x: float, y: float, z: float, h: float, r: float) -> str:
    kind = rng.choice(["box", "sphere", "cylinder", "capsule", "ellipsoid"])
    size = {"box": f"{r:.3f} {0.6 * r:.3f} {rng.uniform(0.5, 1.5) * r:.3f}", "sphere": f"{r:.3f}", "cylinder": f"{0.7 * r:.3f} {r:.3f}",
            "capsule": f"{0.5 * r:.3f} {0.7 * r:.3f}", "ellipsoid": f"{r:.3f} {0.6 * r:.3f} {0.8 * r:.3f}"}[kind]  # fmt: skip
    return f'<geom type="{kind}" pos="{x:.3f} {y:.3f} {z:.3f}" euler="0 {rng.uniform(-40, 40):.1f} 0" size="{size}" rgba="{_rgba(h, rng)}"/>'


def props_xml(spec: dict[str, Any], half_w: float) -> str:
    """Static coloured shapes (seeded by the entry's name): 1 to 2 in the foreground (0.5 to 0.8 m in front of the
    plane of motion) and 1 to 3 behind it, all inside the view (``half_w``: its half width at the plane of motion, m)
    and off the object's swept area; with ``clutter``, :data:`CLUTTER_N` more on the wall, anywhere, none of the
    object's hue."""
    rng = np.random.default_rng([int(hashlib.sha1(spec["name"].encode()).hexdigest()[:8], 16), 67])
    x0, x1, z0, z1 = _keep_out(spec["system"], float(spec["scale"]))
    out = []
    for depth, n in ((rng.uniform(-0.8, -0.5), int(rng.integers(1, 3))), (rng.uniform(0.1, 0.25), int(rng.integers(1, 4)))):
        for _ in range(n):
            for _try in range(200):
                r = rng.uniform(0.05, 0.1)
                xp, zp = rng.uniform(-half_w + r, half_w - r), rng.uniform(0.05 + r, 1.65 - r)
                if (xp + r < x0 or xp - r > x1 or zp + r < z0 or zp - r > z1) and (spec["mover"] is None or np.hypot(*(np.subtract([xp, zp], spec["mover_at"]))) > 0.35):
                    x, z = _world(xp, zp, depth)
                    out.append(_shape(rng, x, depth, z, rng.uniform(0, 1), r * (_CAM_Y + depth) / _CAM_Y))
                    break
    if spec["backdrop"] == "clutter":
        avoid = _COLOUR[spec["system"]]
        for _ in range(CLUTTER_N):
            h = rng.uniform(0, 1)
            while min(abs(h - avoid), 1 - abs(h - avoid)) < 0.07:
                h = rng.uniform(0, 1)
            x, z = rng.uniform(-1.7, 1.7), rng.uniform(-0.05, 1.85)
            out.append(_shape(rng, x, _WALL_Y - 0.06, z, h, rng.uniform(0.04, 0.11)))
    return "\n".join(out)


def _mover_xml(spec: dict[str, Any]) -> str:
    """The mover's MJCF body (one hinge about the camera axis), behind the plane of motion at ``mover_at``."""
    y = 0.2
    x, z = _world(*spec["mover_at"], y)
    if spec["mover"] == "fan":
        blades = "".join(f'<geom type="box" pos="{0.09 * math.cos(a):.3f} 0 {0.09 * math.sin(a):.3f}" euler="0 {-math.degrees(a):.1f} 0" '
                         f'size="0.08 0.005 0.025" rgba="{c}"/>' for a, c in zip((0, 2 * math.pi / 3, 4 * math.pi / 3), ("0.95 0.75 0.1 1", "0.1 0.7 0.75 1", "0.9 0.35 0.6 1")))  # fmt: skip
        return (f'<geom type="cylinder" fromto="{x:.3f} {y + 0.01:.3f} {z:.3f} {x:.3f} {y + 0.01:.3f} -0.05" size="0.012" rgba="0.3 0.3 0.3 1"/>'
                f'<body name="fan" pos="{x:.3f} {y - 0.02:.3f} {z:.3f}"><joint name="fan" type="hinge" axis="0 1 0"/>'
                f'<geom type="sphere" size="0.025" rgba="0.2 0.2 0.2 1"/>{blades}</body>')  # fmt: skip
    leaves = "".join(f'<geom type="ellipsoid" pos="{0.07 * sx:.3f} 0 {hz:.3f}" euler="0 {-40 * sx:.0f} 0" size="0.075 0.01 0.03" rgba="0.2 {0.45 + 0.05 * (i % 3):.2f} 0.15 1"/>'
                     for i, (sx, hz) in enumerate(((1, 0.25), (-1, 0.33), (1, 0.42), (-1, 0.5), (1, 0.58), (-1, 0.64))))  # fmt: skip
    return (f'<geom type="cylinder" pos="{x:.3f} {y:.3f} {z - 0.06:.3f}" size="0.08 0.07" rgba="0.75 0.4 0.2 1"/>'
            f'<body name="plant" pos="{x:.3f} {y:.3f} {z:.3f}"><joint name="plant" type="hinge" axis="0 1 0"/>'
            f'<geom type="capsule" fromto="0 0 0 0 0 0.7" size="0.012" rgba="0.25 0.45 0.15 1"/>{leaves}</body>')  # fmt: skip


def _scale_body(body: ET.Element, s: float) -> None:
    for g in body.iter("geom"):
        for key in ("size", "pos"):
            if key in g.attrib:
                g.set(key, " ".join(f"{float(v) * s:g}" for v in g.get(key).split()))


def backdrop_scene(spec: dict[str, Any], half_w: float = 0.8) -> str:
    """MJCF of the entry's scene: the suite's room (:func:`~lagsplat.synth.realistic.scene.scene_xml`) with the wall's
    material replaced by the backdrop, the crate, bottle and second cart taken out, the object scaled by ``scale``,
    the props, the mover and the moving key light added (joints, when any, last in ``qpos``: mover, light).
    ``half_w``: the view's half width at the plane of motion, m (0.8 times width over height)."""
    system, s = spec["system"], float(spec["scale"])
    pend = {"pivot_z": _pivot_z(s), "rod": ROD_M * s, "string": 0.012 * s, "bob": 0.06 * s} if system == "pendulum" else None
    root = ET.fromstring(scene_xml(system, distance_m=_CAM_Y, pendulum=pend))
    world, asset = root.find("worldbody"), root.find("asset")
    for name in ("crate", "bottle"):
        world.remove(world.find(f"geom[@name='{name}']"))
    for b in world.iter("body"):
        if b.get("name") == "cart2":  # static unless it is the missing degree of freedom: hidden (group 3)
            for g in b.iter("geom"):
                g.set("group", "3")
        elif b.get("name") in ("cart", "disk"):
            _scale_body(b, s)
            if b.get("name") == "cart":
                b.set("pos", f"0 0 {0.49 + 0.05 * s + 0.02:g}")
    wall, bd = world.find("geom[@name='wall']"), spec["backdrop"]
    if bd == "checker":
        ET.SubElement(asset, "texture", name="bd", type="2d", builtin="checker", rgb1="0.04 0.04 0.04", rgb2="0.96 0.96 0.96", width="64", height="64")
        ET.SubElement(asset, "material", name="bd", texture="bd", texuniform="true", texrepeat=f"{1 / CHECKER_M:g} {1 / CHECKER_M:g}")
    elif bd == "wood":
        ET.SubElement(asset, "texture", name="bd", type="2d", file=_png("wood", wood_texture(int(spec["seed"]))))
        ET.SubElement(asset, "material", name="bd", texture="bd", texuniform="true", texrepeat="0.8 0.8")
    elif bd in PHOTOS:
        wall.set("size", "1.7 1.2 0.1")  # one copy of the photograph fills the view
        ET.SubElement(asset, "texture", name="bd", type="2d", file=_png(bd, _photo(bd, 1.7 / 1.2)))
        ET.SubElement(asset, "material", name="bd", texture="bd", texrepeat="1 1")
    elif bd == "clutter":
        ET.SubElement(asset, "material", name="bd", rgba="0.5 0.58 0.47 1")  # sage green: the beige disk stands out
    else:
        raise ValueError(f"unknown backdrop {bd!r}; known: checker, wood, clutter, {', '.join(PHOTOS)}")
    wall.set("material", "bd")
    extra = props_xml(spec, half_w) + (_mover_xml(spec) if spec["mover"] else "")
    if spec["moving_light"]:
        key = world.find("light[@name='key']")
        world.remove(key)
        extra += ('<body name="lamp" pos="-0.6 -1.2 2.2"><joint name="lamp" type="slide" axis="1 0 0"/>'
                  '<inertial pos="0 0 0" mass="0.1" diaginertia="1e-3 1e-3 1e-3"/>'
                  '<light name="key" pos="0 0 0" dir="0.3 0.6 -0.8" castshadow="true" cutoff="55" exponent="6" diffuse="0.95 0.9 0.85"/></body>')  # fmt: skip
    for el in ET.fromstring(f"<w>{extra}</w>"):
        world.append(el)
    return ET.tostring(root, encoding="unicode")
