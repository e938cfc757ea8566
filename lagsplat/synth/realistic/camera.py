"""Filming a realistic-suite scene: MuJoCo's offscreen renderer, then what a real camera adds.

After rendering (EGL; ``MUJOCO_GL=egl`` is set unless the user chose a
backend), each frame gets a vignette (a lighting gradient towards the
corners), Gaussian sensor noise (``noise_std`` grey levels, seeded) and is
written as MP4 (OpenCV's ``mp4v`` codec: lossy, blocky at low bit rates). The
writer goes through a temporary file and an atomic rename.
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from lagsplat.synth.realistic.scene import qpos_of, scene_xml

__all__ = ["import_mujoco", "offscreen", "render_frames", "add_camera_nuisances", "write_mp4"]

# MuJoCo picks its GL backend when it is first imported: offscreen EGL unless the user chose one
os.environ.setdefault("MUJOCO_GL", "egl")


def import_mujoco():
    """The ``mujoco`` module (with ``MUJOCO_GL`` set as the module docstring says).

    Raises:
        ImportError: naming the optional dependency group to install.
    """
    try:
        import mujoco
    except ImportError as exc:  # an optional dependency: pip install -e .[suite]
        raise ImportError("the realistic suite renders with MuJoCo: pip install -e '.[suite]'") from exc
    return mujoco


def offscreen(xml: str, width: int, height: int):
    """MuJoCo model, data and offscreen renderer of the scene ``xml`` at ``width x height``.

    Raises:
        ImportError: without MuJoCo.
        RuntimeError: naming the GL backend when no offscreen context can be made.
    """
    mujoco = import_mujoco()
    model = mujoco.MjModel.from_xml_string(xml)
    model.vis.global_.offwidth, model.vis.global_.offheight = max(width, 640), max(height, 480)
    data = mujoco.MjData(model)
    try:
        renderer = mujoco.Renderer(model, height, width)
    except Exception as exc:  # noqa: BLE001 - GL errors come in several types
        raise RuntimeError(f"MuJoCo cannot render offscreen with MUJOCO_GL={os.environ.get('MUJOCO_GL')}: {exc}") from exc
    return model, data, renderer


def render_frames(
    system: str, q: np.ndarray, width: int, height: int, xml: str | None = None, extra_qpos: np.ndarray | None = None
) -> np.ndarray:
    """Render ``q [T, d]`` (ground-truth coordinates) of ``system`` to uint8 RGB frames ``[T, height, width, 3]``.

    Args:
        xml: the scene's MJCF (default :func:`~lagsplat.synth.realistic.scene.scene_xml` of ``system``).
        extra_qpos: ``[T, k]`` joint positions (m, rad) of the extra bodies of such a scene
            (``scene_xml(..., extra_xml=...)``), written into the last ``k`` entries of ``qpos`` per frame.

    Raises:
        ImportError: without MuJoCo.
        RuntimeError: naming the GL backend when no offscreen context can be made.
    """
    mujoco = import_mujoco()
    model, data, renderer = offscreen(xml or scene_xml(system, distance_m=2.2), width, height)
    out = np.empty((len(q), height, width, 3), np.uint8)
    cam = model.camera("cam").id
    extra = None if extra_qpos is None else np.asarray(extra_qpos, np.float64).reshape(len(q), -1)
    try:
        for i, qi in enumerate(np.asarray(q)):
            qp = qpos_of(system, qi)
            data.qpos[: len(qp)] = qp
            if extra is not None and extra.shape[1]:
                data.qpos[model.nq - extra.shape[1] :] = extra[i]
            mujoco.mj_kinematics(model, data)
            mujoco.mj_camlight(model, data)  # camera and light poses (mj_kinematics leaves them at zero)
            renderer.update_scene(data, camera=cam)
            out[i] = renderer.render()
    finally:
        renderer.close()
    return out


def add_camera_nuisances(frames: np.ndarray, noise_std: float, seed: int, vignette: float = 0.35) -> np.ndarray:
    """A vignette (brightness ``1 - vignette r^2``, ``r`` the distance from the centre over the half-diagonal)
    and Gaussian sensor noise of ``noise_std`` grey levels, seeded; uint8 in and out."""
    T, H, W, _ = frames.shape
    yy, xx = np.mgrid[0:H, 0:W]
    r2 = ((xx - (W - 1) / 2) ** 2 + (yy - (H - 1) / 2) ** 2) / (((W - 1) / 2) ** 2 + ((H - 1) / 2) ** 2)
    gain = (1.0 - vignette * r2)[None, :, :, None]
    rng = np.random.default_rng([int(seed), 99])
    noisy = frames.astype(np.float32) * gain + rng.normal(0.0, noise_std, size=frames.shape).astype(np.float32)
    return np.clip(noisy + 0.5, 0, 255).astype(np.uint8)


def write_mp4(frames: np.ndarray, path: str | Path, fps: float) -> Path:
    """Write uint8 RGB ``frames [T, H, W, 3]`` as an MP4 (``mp4v``) atomically.

    Raises:
        OSError: if OpenCV cannot open a writer for the file.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.tmp{os.getpid()}.mp4")
    H, W = frames.shape[1:3]
    vw = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*"mp4v"), float(fps), (W, H))
    if not vw.isOpened():
        raise OSError(f"{path}: OpenCV cannot open an mp4v writer")
    try:
        for f in frames:
            vw.write(cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
    finally:
        vw.release()
    os.replace(tmp, path)
    return path
