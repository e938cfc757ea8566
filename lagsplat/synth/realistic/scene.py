"""MuJoCo scenes of the realistic suite: the moving system in front of a cluttered, textured, shadowed backdrop.

MuJoCo is only the renderer here (its physics never steps): the motion comes
from :mod:`lagsplat.synth.realistic.motion` and is written into ``qpos`` frame
by frame. Every scene has the same room: a camera looking along ``+y`` at the
``x``-``z`` plane where the object moves, a checkered backdrop wall and a
textured floor, two static distractor objects, a shadow-casting spot light
from the upper left (the object's shadow moves on the wall) and a dim fill
light from the right (a lighting gradient across the frame).

Units: metres, radians. The view is :data:`VIEW_WIDTH_M` wide at the object's plane.
"""

from __future__ import annotations

__all__ = ["scene_xml", "VIEW_WIDTH_M", "ROD_M", "ROOM_XML", "qpos_of"]

import numpy as np

VIEW_WIDTH_M = 1.6
"""Width of the camera's view at the plane of motion, m."""

ROD_M = 0.5
"""Pendulum rod length, m (the double pendulum's rods are 0.3 m, :mod:`lagsplat.synth.realistic.motion`)."""

ROOM_XML = """
  <asset>
    <texture name="wall" type="2d" builtin="checker" rgb1="0.62 0.58 0.52" rgb2="0.42 0.40 0.37" width="256" height="256" mark="random" random="0.04" markrgb="0.8 0.8 0.8"/>
    <material name="wall" texture="wall" texrepeat="6 6" reflectance="0"/>
    <texture name="floor" type="2d" builtin="gradient" rgb1="0.35 0.30 0.26" rgb2="0.22 0.2 0.18" width="128" height="128"/>
    <material name="floor" texture="floor" texrepeat="4 4"/>
  </asset>
  <visual><quality shadowsize="2048"/><headlight ambient="0.25 0.25 0.25" diffuse="0.2 0.2 0.2" specular="0 0 0"/></visual>
  <worldbody>
    <camera name="cam" pos="0 -{dist} 0.85" xyaxes="1 0 0 0 0 1" fovy="{fovy}"/>
    <light name="key" pos="-0.9 -1.2 2.2" dir="0.45 0.6 -0.8" castshadow="true" cutoff="50" exponent="8" diffuse="0.9 0.88 0.82"/>
    <light name="fill" pos="1.5 -1.0 1.0" dir="-1 0.6 -0.2" castshadow="false" diffuse="0.18 0.2 0.24"/>
    <geom name="wall" type="plane" pos="0 0.35 0.8" zaxis="0 -1 0" size="3 3 0.1" material="wall"/>
    <geom name="floor" type="plane" pos="0 0 -0.05" size="3 3 0.1" material="floor"/>
    <geom name="crate" type="box" pos="-0.6 0.2 0.08" size="0.1 0.08 0.13" rgba="0.55 0.35 0.2 1"/>
    <geom name="bottle" type="cylinder" pos="0.62 0.15 0.1" size="0.045 0.15" rgba="0.2 0.45 0.3 1"/>
{body}
  </worldbody>
"""
"""The room of every scene (``{dist}``: camera distance, m; ``{fovy}``: its vertical field of view, degrees; ``{body}``:
the moving system's MJCF); the camera is named ``cam``."""

_BODIES = {
    "pendulum": """
    <body name="slider" pos="0 0 {pivot_z}"><joint name="pivot_x" type="slide" axis="1 0 0"/>
      <geom type="box" size="0.05 0.03 0.02" rgba="0.2 0.2 0.22 1"/>
      <body name="arm"><joint name="theta" type="hinge" axis="0 1 0"/>
        <geom type="capsule" fromto="0 0 0 0 0 -{rod}" size="{string}" rgba="0.75 0.75 0.78 1"/>
        <geom type="sphere" pos="0 0 -{rod}" size="{bob}" rgba="0.85 0.2 0.12 1"/>
      </body>
    </body>""",
    "spring_cart": """
    <geom type="box" pos="0 0 0.48" size="0.75 0.04 0.01" rgba="0.3 0.3 0.32 1"/>
    <geom type="box" pos="-0.74 0 0.6" size="0.015 0.05 0.13" rgba="0.25 0.25 0.27 1"/>
    <geom type="box" pos="0.74 0 0.6" size="0.015 0.05 0.13" rgba="0.25 0.25 0.27 1"/>
    <body name="cart" pos="0 0 0.56"><joint name="x" type="slide" axis="1 0 0"/>
      <geom type="box" size="0.08 0.05 0.05" rgba="0.15 0.35 0.8 1"/>
      <geom type="box" pos="0 -0.051 0.0" size="0.03 0.001 0.03" rgba="0.95 0.85 0.2 1"/>
    </body>
    <body name="cart2" pos="0.35 0 0.56"><joint name="x2" type="slide" axis="1 0 0"/>
      <geom type="box" size="0.05 0.05 0.04" rgba="0.7 0.3 0.6 1"/>
    </body>""",
    "torsion_disk": """
    <geom type="cylinder" pos="0 0.05 0.85" zaxis="0 1 0" size="0.015 0.05" rgba="0.2 0.2 0.2 1"/>
    <body name="disk" pos="0 0 0.85"><joint name="phi" type="hinge" axis="0 1 0"/>
      <geom type="cylinder" zaxis="0 1 0" size="0.2 0.01" rgba="0.8 0.78 0.7 1"/>
      <geom type="box" pos="0 -0.012 0" size="0.17 0.004 0.025" rgba="0.15 0.15 0.6 1"/>
      <geom type="sphere" pos="0.12 -0.015 0.1" size="0.03" rgba="0.9 0.15 0.1 1"/>
    </body>""",
    "double_pendulum": """
    <geom type="box" pos="0 0.02 1.45" size="0.05 0.03 0.02" rgba="0.2 0.2 0.22 1"/>
    <body name="upper" pos="0 0 1.45"><joint name="t1" type="hinge" axis="0 1 0"/>
      <geom type="capsule" fromto="0 0 0 0 0 -0.3" size="0.012" rgba="0.75 0.75 0.78 1"/>
      <geom type="sphere" pos="0 0 -0.3" size="0.045" rgba="0.2 0.5 0.85 1"/>
      <body name="lower" pos="0 0 -0.3"><joint name="t2" type="hinge" axis="0 1 0"/>
        <geom type="capsule" fromto="0 0 0 0 0 -0.3" size="0.012" rgba="0.75 0.75 0.78 1"/>
        <geom type="sphere" pos="0 0 -0.3" size="0.05" rgba="0.85 0.2 0.12 1"/>
      </body>
    </body>""",
}


PENDULUM_GEOMETRY = {"pivot_z": 1.45, "rod": ROD_M, "string": 0.012, "bob": 0.06}
"""The pendulum's default geometry, m (:func:`scene_xml`): pivot height, rod length, string and bob radii."""


def scene_xml(
    system: str, distance_m: float = 2.2, pendulum: dict[str, float] | None = None, extra_xml: str = "", extra_assets: str = ""
) -> str:
    """MJCF of ``system``'s scene; the camera at ``distance_m`` sees :data:`VIEW_WIDTH_M` across (square field).

    Args:
        system: one of the systems of :func:`qpos_of`.
        distance_m: camera distance from the plane of motion, m.
        pendulum: pendulum geometry overrides, m: ``pivot_z`` (pivot height, default 1.45), ``rod``
            (default :data:`ROD_M`), ``string`` (rod radius, default 0.012), ``bob`` (bob radius, default 0.06).
        extra_xml: MJCF bodies appended to the world after the system (their joints come last in ``qpos``).
        extra_assets: an MJCF ``<asset>`` block the extra bodies use (textures, materials).

    Raises:
        ValueError: on an unknown system.
    """
    if system not in _BODIES:
        raise ValueError(f"unknown system {system!r}; known: {sorted(_BODIES)}")
    fovy = float(np.degrees(2 * np.arctan(0.5 * VIEW_WIDTH_M / distance_m)))
    geom = {**PENDULUM_GEOMETRY, **(pendulum or {})}
    body = _BODIES[system]
    for key, value in geom.items():
        body = body.replace("{" + key + "}", f"{value:g}")
    body += extra_xml
    return "<mujoco>" + ROOM_XML.replace("{dist}", f"{distance_m:g}").replace("{fovy}", f"{fovy:.4f}").replace("{body}", body) + extra_assets + "</mujoco>"


def qpos_of(system: str, q: np.ndarray) -> np.ndarray:
    """MuJoCo ``qpos`` of one frame from the ground-truth coordinates ``q [d]`` (:class:`~lagsplat.synth.realistic.motion.Motion`).

    Pendulum: ``(pivot slide m, angle rad)`` (the pivot moves only for ``missing_dof``,
    whose second coordinate is in rod lengths); spring cart: ``(x m, second cart m)``
    (the second cart, at rest 0.35 m to the right, moves only as the missing degree of freedom);
    torsion disk: ``(angle rad)``; double pendulum: ``(upper, lower relative)`` angles.
    A positive pendulum angle swings the bob to the right (MuJoCo's hinge about ``+y`` turns the other way).
    """
    q = np.asarray(q, np.float64)
    if system == "pendulum":
        pivot = q[1] * ROD_M if len(q) > 1 else 0.0
        return np.array([pivot, -q[0]])
    if system == "spring_cart":
        return np.array([q[0], q[1] if len(q) > 1 else 0.0])
    if system == "torsion_disk":
        return np.array([-q[0]])
    if system == "double_pendulum":
        return np.array([-q[0], -(q[1] - q[0])])
    raise ValueError(f"unknown system {system!r}")
