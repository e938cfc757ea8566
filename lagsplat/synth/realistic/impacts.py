"""Impact clips: the realistic suite's oscillators bouncing off rigid stops (an impact oscillator).

Each entry of :func:`impact_clips` is a pendulum, a spring cart or a torsion disk (the suite's scene,
:mod:`lagsplat.synth.realistic.scene`) released at the amplitude :data:`RELEASE` that meets a rigid
stop on every swing and bounces off it with a coefficient of restitution ``e`` (``restitution``,
0.3 to 0.9): the law of :mod:`lagsplat.synth.realistic.impact_motion`. The library's ``end_stop``
is a stiff elastic spring met only at the largest swings; here the contact is instantaneous and
loses energy.

* one-sided (``sides`` 1, tag ``impact``): one stop at ``stop_frac * A`` (``stop_frac`` a signed
  fraction of the release amplitude ``A``, 0.2 to 0.6 in size), released from rest at ``A`` on the
  other side of the rest position: every swing crosses the rest position and ends on the stop.
* two-sided (``sides`` 2, tag ``impact2``): a stop on each side of the rest position, released from it
  with the speed of a free swing of amplitude ``A`` towards the upper stop (a release from rest at
  ``A`` would be beyond a stop): every half swing ends on a stop while the swings reach both, every swing
  on the nearer one after that.

Each impact takes out ``1 - e^2`` of the kinetic energy at the stop, so the speed at contact falls
by about ``e`` per impact; once the swing only just reaches the stop, the light damping of the smooth
part (``zeta`` 0.001 to 0.002, below the library's 0.004 to 0.012: here the impacts take out the energy)
ends the contacts, and the object swings on just short of the stop. Clips of low ``e`` therefore
show few impacts (3 at ``e = 0.3``, 4 at 0.45), the others 7 to 12 in their 12 s.

A static stop is drawn where the object touches it (:func:`impact_scene`): a dark post with a yellow
pad at the bob's height for the pendulum, a dark block with a yellow pad on the rail for the cart
(the suite's second cart hidden), a dark pin in front of the disk, on an arm from outside its rim,
that the blue bar's edge hits (one end of the bar for a stop below the release angle, the other for
one above, so the red dot never reaches a pin).

Names are ``<system>-impact[2]-e<e>-s<seed>-128``. Every entry has a ``split``: ``test`` or ``tune``,
four each, mixed over the systems and the sides. The test half is frozen: its entries, parameters and
split are never changed, and nothing is tuned on it.

Units: ``q`` and the stops in rad (pendulum, torsion disk) or m (cart), s, Hz.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
import zlib
from typing import Any

import numpy as np

from lagsplat.synth.realistic.impact_motion import impact_trajectory, observed_frequency
from lagsplat.synth.realistic.motion import Motion
from lagsplat.synth.realistic.scene import PENDULUM_GEOMETRY, scene_xml

__all__ = ["impact_clips", "impact_motion", "impact_scene", "stops_of", "release_of", "RELEASE", "DISK_PIN"]

RELEASE = {"pendulum": math.radians(30.0), "spring_cart": 0.28, "torsion_disk": math.radians(60.0)}
"""Release amplitude ``A`` per system, in ``q`` units (rad, m, rad): inside the library's largest excursions
(35 degrees, 0.35 m); the disk at the suite's 60 degrees (at 120 the bar's far end would reach a pin)."""

DISK_PIN = {"radius_m": 0.13, "pin_m": 0.03, "bar_half_m": 0.025}
"""The torsion disk's stop pin: distance of its axis from the disk's, its radius, and the half height of the
disk's bar that hits it, m (the bar is :mod:`~lagsplat.synth.realistic.scene`'s)."""

_CART_HALF_M = 0.08
"""Half length of the suite's cart body, m."""

_DARK, _PAD = "0.12 0.12 0.13 1", "0.95 0.78 0.1 1"
"""Colours of the stops' bodies and of their contact pads."""


def _entry(system: str, e: float, seed: int, stop_frac: list[float], split: str) -> dict[str, Any]:
    tag = "impact" if len(stop_frac) == 1 else "impact2"
    return {"name": f"{system}-{tag}-e{e:g}-s{seed}-128", "system": system, "effect": "end_stop", "kind": "impact", "variant": f"s{seed}",
            "size": "128", "seed": seed, "sides": len(stop_frac), "stop_frac": list(stop_frac), "restitution": e, "split": split}  # fmt: skip


def impact_clips() -> list[dict[str, Any]]:
    """The impact clips (module docstring): ``{name, system, effect, kind, variant, size, seed, sides, stop_frac,
    restitution, split}``; ``effect`` is ``end_stop`` (the diagnosis library's label for a stop), ``kind`` is ``impact``.

    Not part of :func:`~lagsplat.synth.realistic.realistic_suite`; rendered by the Snakemake target ``realistic_impacts``.
    The ``test`` half is frozen (module docstring).
    """
    return [
        _entry("pendulum", 0.9, 0, [-0.4], "test"),
        _entry("spring_cart", 0.6, 0, [-0.4, 0.35], "test"),
        _entry("torsion_disk", 0.8, 1, [0.2], "test"),
        _entry("pendulum", 0.3, 1, [-0.45, 0.4], "test"),
        _entry("spring_cart", 0.85, 1, [-0.5], "tune"),
        _entry("torsion_disk", 0.45, 0, [-0.4, 0.55], "tune"),
        _entry("pendulum", 0.75, 2, [0.6], "tune"),
        _entry("spring_cart", 0.7, 2, [-0.35, 0.3], "tune"),
    ]


def stops_of(spec: dict[str, Any]) -> tuple[float, ...]:
    """The entry's stop positions in ``q`` units (``stop_frac`` times :data:`RELEASE`)."""
    return tuple(float(f) * RELEASE[spec["system"]] for f in spec["stop_frac"])


def _draw(spec: dict[str, Any]) -> tuple[float, float]:
    """``(f0_hz, zeta)``, seeded by the entry's seed and name: 0.6 to 1.0 Hz (the library's range), 0.001 to 0.002."""
    rng = np.random.default_rng([int(spec["seed"]), 83, zlib.crc32(spec["name"].encode())])
    return float(rng.uniform(0.6, 1.0)), float(rng.uniform(0.001, 0.002))


def release_of(spec: dict[str, Any], w0: float) -> tuple[float, float]:
    """The release state ``(x0, v0)`` (module docstring); ``w0`` the angular frequency, rad/s.

    Raises:
        ValueError: unless the entry has one stop, or two on opposite sides of the rest position.
    """
    A, fr = RELEASE[spec["system"]], [float(f) for f in spec["stop_frac"]]
    if len(fr) == 1 and fr[0] != 0:
        return -math.copysign(A, fr[0]), 0.0
    if len(fr) == 2 and fr[0] * fr[1] < 0:  # the speed at the rest position of a swing of amplitude A
        return 0.0, (2 * w0 * math.sin(A / 2) if spec["system"] == "pendulum" else w0 * A)
    raise ValueError(f"{spec['name']}: stop_frac {fr} must be one nonzero fraction or two of opposite signs")


def impact_motion(spec: dict[str, Any], fps: float = 30.0, duration_s: float = 12.0) -> Motion:
    """The ground-truth motion of one :func:`impact_clips` entry (:func:`~lagsplat.synth.realistic.impact_motion.impact_trajectory`).

    ``truth`` has ``system``, ``effect`` (``end_stop``), ``kind`` (``impact``), ``f0_hz``, ``zeta``, ``amplitude``
    (``A``, ``q`` units; ``amplitude_deg`` too for the pendulum and disk), ``stops`` (``q`` units), ``sides``,
    ``restitution``, ``release`` (``x0``, ``v0``), ``f_observed_hz`` (turning points over the moving part, Hz,
    :func:`~lagsplat.synth.realistic.impact_motion.observed_frequency`), ``f_impacting_hz`` (the same up to the
    last contact), ``n_impacts``, ``last_impact_s``, ``rest_s`` (``None`` unless it comes to rest against a stop)
    and ``impacts`` (``t_s``, ``stop``: index into ``stops``, ``v_pre``, ``v_post``, per contact, ``q`` units per s).
    """
    system = spec["system"]
    f0, zeta = _draw(spec)
    w0 = 2 * math.pi * f0
    x0, v0 = release_of(spec, w0)
    stops, e = stops_of(spec), float(spec["restitution"])
    t = np.arange(int(round(duration_s * fps))) / fps
    run = impact_trajectory(w0, zeta, system == "pendulum", stops, e, x0, v0, t)
    A = RELEASE[system]
    last = float(run.impact_t[-1]) if len(run.impact_t) else None
    truth = {"system": system, "effect": "end_stop", "kind": "impact", "f0_hz": f0, "zeta": zeta, "amplitude": A, "stops": list(stops),
             "sides": len(stops), "restitution": e, "actuated": False, "release": {"x0": x0, "v0": v0},
             "f_observed_hz": observed_frequency(run), "f_impacting_hz": observed_frequency(run, until=last),
             "n_impacts": int(len(run.impact_t)), "last_impact_s": last, "rest_s": run.rest_s,
             "impacts": {"t_s": run.impact_t.tolist(), "stop": run.impact_stop.tolist(), "v_pre": run.v_pre.tolist(), "v_post": run.v_post.tolist()},
             "effect_params": {"kind": "impact", "x_stops": list(stops), "restitution": e}}  # fmt: skip
    if system != "spring_cart":
        truth["amplitude_deg"] = math.degrees(A)
    return Motion(t, run.x[:, None], run.xdot[:, None], run.hidden, f0, truth)


def _box(x: float, z: float, half: tuple[float, float, float], rgba: str, angle: float = 0.0, y: float = 0.0) -> str:
    """A static box at ``(x, y, z)`` (m) turned by ``angle`` (rad) in the plane of motion (its ``+x`` towards polar ``angle``)."""
    return (f'<geom type="box" pos="{x:.4f} {y:.4f} {z:.4f}" euler="0 {-math.degrees(angle):.3f} 0" '
            f'size="{half[0]:.4f} {half[1]:.4f} {half[2]:.4f}" rgba="{rgba}"/>')  # fmt: skip


def _pendulum_stop(x_s: float, side: float) -> str:
    """A post from the floor with a pad whose face the bob touches when the angle is ``x_s`` (rad)."""
    rod, bob, pz = PENDULUM_GEOMETRY["rod"], PENDULUM_GEOMETRY["bob"], PENDULUM_GEOMETRY["pivot_z"]
    bx, bz = rod * math.sin(x_s), pz - rod * math.cos(x_s)
    face, top = bx + side * bob, bz + 0.03
    return (_box(face + side * 0.006, bz, (0.006, 0.035, 0.03), _PAD)
            + _box(face + side * 0.032, (top - 0.05) / 2, (0.02, 0.03, (top + 0.05) / 2), _DARK))  # fmt: skip


def _cart_stop(x_s: float, side: float) -> str:
    """A block standing on the rail with a pad whose face the cart touches when its centre is at ``x_s`` (m)."""
    face = x_s + side * _CART_HALF_M
    return _box(face + side * 0.006, 0.56, (0.006, 0.05, 0.04), _PAD) + _box(face + side * 0.037, 0.56, (0.025, 0.05, 0.07), _DARK)


def _disk_stop(x_s: float, side: float) -> str:
    """A pin in front of the disk (axis along the view) that the bar's edge touches when the angle is ``x_s`` (rad),
    held by an arm from outside the rim. A stop below the release angle is met by the bar's ``+x`` end, one above by
    its ``-x`` end; the pin sits ``asin((bar_half + pin) / radius)`` beyond the end's angle at contact."""
    R, r, h = DISK_PIN["radius_m"], DISK_PIN["pin_m"], DISK_PIN["bar_half_m"]
    delta = math.asin((h + r) / R)
    phi = x_s - delta if side < 0 else math.pi + x_s + delta
    px, pz = R * math.cos(phi), 0.85 + R * math.sin(phi)
    arm_in, arm_out = R, 0.32
    mid = (arm_in + arm_out) / 2
    pin = f'<geom type="cylinder" pos="{px:.4f} -0.04 {pz:.4f}" zaxis="0 1 0" size="{r:g} 0.028" rgba="{_DARK}"/>'
    return pin + _box(mid * math.cos(phi), 0.85 + mid * math.sin(phi), ((arm_out - arm_in) / 2, 0.008, 0.01), _DARK, angle=phi, y=-0.06)


def impact_scene(spec: dict[str, Any]) -> str:
    """MJCF of the entry's scene: the suite's room and object (:func:`~lagsplat.synth.realistic.scene.scene_xml`) with
    a static stop drawn at each of :func:`stops_of` (module docstring); for the cart the suite's second cart is hidden
    (geom group 3; its joint stays, so ``qpos`` is the suite's).

    Raises:
        ValueError: on a system other than ``pendulum``, ``spring_cart`` or ``torsion_disk``.
    """
    system = spec["system"]
    draw = {"pendulum": _pendulum_stop, "spring_cart": _cart_stop, "torsion_disk": _disk_stop}.get(system)
    if draw is None:
        raise ValueError(f"no impact scene for {system!r}; known: pendulum, spring_cart, torsion_disk")
    x0, _ = release_of(spec, 1.0)
    stops = "".join(draw(s, 1.0 if s > x0 else -1.0) for s in stops_of(spec))
    root = ET.fromstring(scene_xml(system, distance_m=2.2, extra_xml=stops))
    for b in root.find("worldbody").iter("body"):
        if b.get("name") == "cart2":
            for g in b.iter("geom"):
                g.set("group", "3")
    return ET.tostring(root, encoding="unicode")
