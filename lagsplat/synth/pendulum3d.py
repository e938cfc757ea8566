"""A 3-D test system with ground truth: a pendulum swinging in a plane oblique to the main camera, filmed by
MuJoCo (an independent renderer) from the main camera and from extra cameras around it.

The swing plane is turned by :data:`OBLIQUE_DEG` about the vertical from the main camera's image plane, so the
bob comes towards and goes away from the camera as it swings: depth changes along the motion, which a 2-D
model cannot express. The room is the realistic suite's (:mod:`lagsplat.synth.realistic.scene`: textured wall
and floor, distractors, a shadow-casting light). MuJoCo only renders; the motion is a damped pendulum
``theta'' = -(g / L) sin theta - 2 zeta w0 theta'`` integrated here.

Outputs of :func:`make_pendulum3d` (``<out>`` a path without suffix):

* ``<out>.npz``: ``images [T,H,W,3]`` uint8 (the main camera), ``t [T]`` s;
* ``<out>.views.npz``: ``images [T,M,H,W,3]`` uint8, the same instants seen by the ``M`` extra cameras;
* ``<out>.cameras.json``: ``M + 1`` cameras (:mod:`lagsplat.render.camera` records, world units metres), the
  main camera first;
* ``<out>.truth.npz``: ``q [T,1]`` (rad), ``qdot [T,1]`` (rad/s), ``bob [T,3]`` (world position of the bob
  centre, m), ``f0_hz`` (small-amplitude frequency), ``zeta``, ``L`` (m).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from lagsplat.render.camera import Camera, save_cameras

__all__ = ["OBLIQUE_DEG", "ROD_M", "PIVOT", "swing_axes", "scene3d_xml", "pendulum3d_motion", "render_views", "make_pendulum3d", "main"]

OBLIQUE_DEG = 45.0
"""Angle between the swing plane and the main camera's image plane, degrees."""

ROD_M = 0.5
"""Pivot to bob centre, m."""

PIVOT = (0.0, 0.0, 1.3)
"""World position of the pivot, m (MuJoCo's frame: z up; the main camera looks along +y)."""

_G = 9.81


def swing_axes() -> tuple[np.ndarray, np.ndarray]:
    """Unit horizontal direction of the swing ``d`` and the hinge axis ``n`` (world)."""
    a = math.radians(OBLIQUE_DEG)
    d = np.array([math.cos(a), math.sin(a), 0.0])
    return d, np.cross(d, [0.0, 0.0, 1.0])


def scene3d_xml(extra: list[Camera], fovy_deg: float) -> str:
    """MJCF of the scene with the main camera ``main`` and the extra cameras ``view0 ..`` (given in the
    convention of :mod:`lagsplat.render.camera`)."""
    from lagsplat.synth.realistic.scene import ROOM_XML

    _, n = swing_axes()
    body = f"""
    <geom type="box" pos="{PIVOT[0]} {PIVOT[1] + 0.03} {PIVOT[2] + 0.02}" size="0.06 0.03 0.02" rgba="0.2 0.2 0.22 1"/>
    <body name="arm" pos="{PIVOT[0]} {PIVOT[1]} {PIVOT[2]}"><joint name="theta" type="hinge" axis="{n[0]:.6f} {n[1]:.6f} {n[2]:.6f}"/>
      <geom type="capsule" fromto="0 0 0 0 0 -{ROD_M}" size="0.012" rgba="0.75 0.75 0.78 1"/>
      <geom name="bob" type="sphere" pos="0 0 -{ROD_M}" size="0.06" rgba="0.85 0.2 0.12 1"/>
    </body>"""
    cams = []
    for i, c in enumerate(extra):
        R = np.asarray(c.R)
        x, y = R[0], -R[1]  # MuJoCo's camera: x right, y up, looking along -z
        p = c.center
        cams.append(f'    <camera name="view{i}" pos="{p[0]:.6f} {p[1]:.6f} {p[2]:.6f}" xyaxes="{x[0]:.6f} {x[1]:.6f} {x[2]:.6f} {y[0]:.6f} {y[1]:.6f} {y[2]:.6f}" fovy="{fovy_deg:.4f}"/>')
    room = ROOM_XML.replace("{dist}", "2.2").replace("{fovy}", f"{fovy_deg:.4f}").replace('<camera name="cam"', '<camera name="main"')
    return "<mujoco>" + room.replace("{body}", body + "\n" + "\n".join(cams)) + "</mujoco>"


def pendulum3d_motion(fps: float, duration_s: float, amplitude_deg: float = 40.0, zeta: float = 0.01, seed: int = 0) -> dict[str, np.ndarray | float]:
    """The damped pendulum's truth: ``t [T]``, ``q [T,1]`` (rad), ``qdot [T,1]``, ``bob [T,3]`` (m), ``f0_hz``, ``zeta``, ``L``.

    The release angle is ``amplitude_deg`` times a seeded factor in [0.85, 1], released from rest.
    """
    from scipy.integrate import solve_ivp

    rng = np.random.default_rng([int(seed), 3])
    th0 = math.radians(amplitude_deg) * float(rng.uniform(0.85, 1.0))
    w0 = math.sqrt(_G / ROD_M)
    t = np.arange(int(round(duration_s * fps))) / fps
    sol = solve_ivp(lambda _, y: [y[1], -(w0**2) * math.sin(y[0]) - 2 * zeta * w0 * y[1]], (0.0, float(t[-1])), [th0, 0.0],
                    t_eval=t, rtol=1e-10, atol=1e-12, method="DOP853")  # fmt: skip
    th, thd = sol.y
    d, _ = swing_axes()
    bob = np.asarray(PIVOT)[None] + ROD_M * (np.sin(th)[:, None] * d[None] - np.cos(th)[:, None] * np.array([0.0, 0.0, 1.0])[None])
    return {"t": t, "q": th[:, None], "qdot": thd[:, None], "bob": bob, "f0_hz": w0 / (2 * math.pi), "zeta": zeta, "L": ROD_M}


def _camera_of(model, data, cam_id: int, width: int, height: int) -> Camera:
    """Our camera record of MuJoCo camera ``cam_id`` after ``mj_camlight``: OpenCV axes ``(x, -y, -z)`` of MuJoCo's."""
    xmat = np.asarray(data.cam_xmat[cam_id]).reshape(3, 3)  # columns: the camera's axes in world coordinates
    R = np.stack([xmat[:, 0], -xmat[:, 1], -xmat[:, 2]])
    f = 0.5 * height / math.tan(math.radians(float(model.cam_fovy[cam_id])) / 2)
    return Camera(width, height, f, f, width / 2.0, height / 2.0, tuple(map(tuple, R)), tuple(-R @ np.asarray(data.cam_xpos[cam_id])))


def render_views(q: np.ndarray, extra: list[Camera], width: int, height: int, fovy_deg: float) -> tuple[np.ndarray, np.ndarray, list[Camera]]:
    """Render the angles ``q [T,1]`` from the main camera and the ``extra`` cameras.

    Returns:
        ``(main [T,H,W,3], views [T,M,H,W,3], cameras)`` with the cameras as MuJoCo placed them (main first).

    Raises:
        ImportError: without MuJoCo. RuntimeError: when no offscreen GL context can be made.
    """
    from lagsplat.synth.realistic.camera import import_mujoco, offscreen

    mujoco = import_mujoco()
    model, data, renderer = offscreen(scene3d_xml(extra, fovy_deg), width, height)
    ids = [model.camera("main").id] + [model.camera(f"view{i}").id for i in range(len(extra))]
    T, M = len(q), len(extra)
    main = np.empty((T, height, width, 3), np.uint8)
    views = np.empty((T, M, height, width, 3), np.uint8)
    cams: list[Camera] = []
    try:
        for i, qi in enumerate(np.asarray(q)):
            data.qpos[0] = float(qi[0])  # a positive angle about n = d x z swings the bob towards +d
            mujoco.mj_kinematics(model, data)
            mujoco.mj_camlight(model, data)
            if i == 0:
                cams = [_camera_of(model, data, c, width, height) for c in ids]
            for k, c in enumerate(ids):
                renderer.update_scene(data, camera=c)
                (main if k == 0 else views[:, k - 1])[i] = renderer.render()
    finally:
        renderer.close()
    return main, views, cams


def make_pendulum3d(out: str | Path, fps: float = 30.0, duration_s: float = 12.0, size: int = 96, n_views: int = 6, seed: int = 0,
                    noise_std: float = 2.0) -> Path:  # fmt: skip
    """Render the 3-D test system (module docstring) to ``<out>.npz`` and its sidecars; returns ``<out>.npz``.

    The extra cameras stand on an arc around the pendulum's mid-swing point, from 50 degrees left to 50 degrees
    right of the main camera, at 10 degrees of elevation; every image gets the realistic suite's vignette and
    seeded sensor noise (``noise_std`` grey levels).
    """
    from lagsplat.io.atomic import write_json, write_npz
    from lagsplat.render.camera import look_at
    from lagsplat.synth.realistic.camera import add_camera_nuisances

    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    m = pendulum3d_motion(fps, duration_s, seed=seed)
    fovy = math.degrees(2 * math.atan(0.5 * 1.2 / 2.2))
    target = np.asarray(PIVOT) - np.array([0.0, 0.0, 0.6 * ROD_M])
    main_dir = np.array([0.0, -2.2, 0.85]) - target
    r = float(np.linalg.norm(main_dir[:2]))
    extra = []
    for k, az in enumerate(np.linspace(-50.0, 50.0, n_views) if n_views > 1 else [30.0]):
        a = math.radians(az) + math.atan2(main_dir[1], main_dir[0])
        eye = target + np.array([r * math.cos(a), r * math.sin(a), r * math.tan(math.radians(10.0))])
        extra.append(look_at(eye, target, (0.0, 0.0, 1.0), size, size, fovy))
    main, views, cams = render_views(m["q"], extra, size, size, fovy)
    main = add_camera_nuisances(main, noise_std, seed)
    views = np.stack([add_camera_nuisances(views[:, k], noise_std, seed + 1 + k) for k in range(views.shape[1])], 1) if n_views else views
    stem = out.with_suffix("")
    write_npz(stem.with_suffix(".npz"), images=main, t=m["t"])
    write_npz(stem.with_suffix(".views.npz"), images=views, t=m["t"])
    write_npz(stem.with_suffix(".truth.npz"), **{k: np.asarray(v) for k, v in m.items()})
    save_cameras(stem.with_suffix(".cameras.json"), cams)
    write_json(stem.with_suffix(".json"), {"fps": fps, "duration_s": duration_s, "size": size, "n_views": n_views, "seed": seed,
                                           "oblique_deg": OBLIQUE_DEG, "f0_hz": m["f0_hz"], "zeta": m["zeta"], "rod_m": ROD_M})  # fmt: skip
    return stem.with_suffix(".npz")


def main(argv: list[str] | None = None) -> int:
    """``python -m lagsplat.synth.pendulum3d --out PATH [--size N --views M --duration-s S --fps F --seed K]``."""
    import argparse

    ap = argparse.ArgumentParser(prog="python -m lagsplat.synth.pendulum3d", description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, help="output path; <out>.npz, .views.npz, .cameras.json, .truth.npz, .json")
    ap.add_argument("--size", type=int, default=96)
    ap.add_argument("--views", type=int, default=6)
    ap.add_argument("--duration-s", type=float, default=12.0)
    ap.add_argument("--fps", type=float, default=30.0)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    print(make_pendulum3d(a.out, a.fps, a.duration_s, a.size, a.views, a.seed))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
