"""The ``sharp`` view source: novel views of every frame from Apple's SHARP (single-image view synthesis).

The paper supervises its 3-D reconstructions with SHARP renders of each frame from other viewpoints (§3.2,
App. C). SHARP (Mescheder et al. 2025, "Sharp Monocular View Synthesis in Less Than a Second") regresses,
from one image, a metric 3-D Gaussian scene in that image's camera frame (OpenCV axes: x right, y down,
z forward). Its command ``sharp predict -i <images> -o <out> -c <checkpoint>`` writes one ``<stem>.ply`` per
image. This module runs it on the clip's frames and renders each scene with this project's own EWA
projection and rasteriser (:mod:`lagsplat.render.camera`, :mod:`lagsplat.render.rasterize`) from view cameras
around the main camera:

* the PLY layout is SHARP's (and the 3-D Gaussian splatting convention): per vertex ``x, y, z``, ``f_dc_0..2``
  (degree-0 spherical harmonics of the sRGB colour, ``rgb = 0.5 + f_dc / (2 sqrt(pi))``), ``opacity`` (a
  logit), ``scale_0..2`` (log standard deviations along the principal axes) and ``rot_0..3`` (a quaternion,
  real part first); the elements ``intrinsic`` (3x3, row-major) and ``image_size`` (width, height) give the
  camera the scene was regressed for (:func:`read_sharp_ply`);
* the world frame is the main camera's: the main camera is ``R = I, t = 0`` with the first scene's focal
  length and principal point scaled to the clip's frames; a scene regressed with other intrinsics is mapped
  into it by the linear map that makes both cameras see the same pixels (:func:`sharp_scene_in`);
* the view cameras stand on a cone around the main camera's axis: ``n_views`` directions evenly spread in
  azimuth, turned by ``angle_deg`` about the point on the axis at the first scene's median depth, all looking
  at that point (:func:`cone_cameras`).

SHARP and its weights are the user's (a GPU machine); the tests run this module against a stand-in command
that writes PLY files of the same layout.
"""

from __future__ import annotations

import math
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import torch

from lagsplat.io.clip import Clip, ClipError
from lagsplat.render.camera import Camera, depth_order, look_at, project_gaussians
from lagsplat.render.rasterize import rasterize

__all__ = ["SharpScene", "read_sharp_ply", "write_sharp_ply", "sharp_scene_in", "cone_cameras", "render_scene", "sharp_views"]

SH_C0 = 0.5 / math.sqrt(math.pi)
"""Degree-0 real spherical harmonic, ``1 / (2 sqrt(pi))``: ``rgb = 0.5 + SH_C0 f_dc``."""


@dataclass
class SharpScene:
    """One frame's 3-D Gaussians as SHARP regressed them, in its camera frame (module docstring).

    Attributes:
        means: ``[N,3]`` metres; covs: ``[N,3,3]`` m^2; colors: ``[N,3]`` sRGB in [0, 1]; opacities: ``[N]``.
        focal_px: the focal length of the camera the scene was regressed for, pixels of ``width x height``.
        width, height: that camera's image size, pixels.
    """

    means: torch.Tensor
    covs: torch.Tensor
    colors: torch.Tensor
    opacities: torch.Tensor
    focal_px: float
    width: int
    height: int


def _quat_to_rot(q: np.ndarray) -> np.ndarray:
    """Rotation matrices ``[N,3,3]`` of quaternions ``[N,4]`` (real part first, normalised by scipy)."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_quat(np.asarray(q, np.float64)[:, [1, 2, 3, 0]]).as_matrix()  # scipy wants the real part last


def read_sharp_ply(path: str | Path) -> SharpScene:
    """Read a SHARP PLY (module docstring) into a :class:`SharpScene`.

    Raises:
        ClipError: naming the file, if it is missing, not a PLY, or lacks a vertex property or the
            ``intrinsic`` / ``image_size`` elements.
    """
    from plyfile import PlyData, PlyParseError

    path = Path(path)
    try:
        ply = PlyData.read(str(path))
        v = ply["vertex"]
    except (OSError, KeyError, ValueError, IndexError, PlyParseError) as e:
        raise ClipError(f"{path}: not a readable PLY with a vertex element: {e}") from e
    names = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity"] + [f"scale_{i}" for i in range(3)] + [f"rot_{i}" for i in range(4)]
    missing = [n for n in names if n not in v.data.dtype.names]
    if missing:
        raise ClipError(f"{path}: vertex properties {missing} missing (a SHARP / 3-D Gaussian splatting PLY has {names})")
    a = {n: np.asarray(v[n], np.float64) for n in names}
    try:
        K = np.asarray(ply["intrinsic"]["intrinsic"], np.float64).reshape(3, 3)
        width, height = (int(s) for s in np.asarray(ply["image_size"]["image_size"]).reshape(-1)[:2])
    except (KeyError, ValueError) as e:
        raise ClipError(f"{path}: the intrinsic (3x3) and image_size elements SHARP writes are missing or malformed: {e}") from e
    R = _quat_to_rot(np.stack([a[f"rot_{i}"] for i in range(4)], 1))
    S = np.exp(np.stack([a[f"scale_{i}"] for i in range(3)], 1))
    covs = R @ (S[:, :, None] ** 2 * np.swapaxes(R, 1, 2))
    colors = np.clip(0.5 + SH_C0 * np.stack([a[f"f_dc_{i}"] for i in range(3)], 1), 0.0, 1.0)
    f = lambda x: torch.as_tensor(x, dtype=torch.float32)  # noqa: E731
    return SharpScene(f(np.stack([a["x"], a["y"], a["z"]], 1)), f(covs), f(colors), f(1.0 / (1.0 + np.exp(-a["opacity"]))),
                      float(K[0, 0]), width, height)  # fmt: skip


def write_sharp_ply(path: str | Path, means: np.ndarray, scales: np.ndarray, quats: np.ndarray, rgb: np.ndarray, opacity: np.ndarray,
                    focal_px: float, width: int, height: int) -> Path:  # fmt: skip
    """Write Gaussians in SHARP's PLY layout (module docstring): ``means [N,3]``, ``scales [N,3]`` (standard
    deviations), ``quats [N,4]`` (real part first), ``rgb [N,3]`` in (0, 1), ``opacity [N]`` in (0, 1). For
    stand-ins of SHARP and for exporting scenes to splat viewers; returns ``path``."""
    from plyfile import PlyData, PlyElement

    props = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity"] + [f"scale_{i}" for i in range(3)] + [f"rot_{i}" for i in range(4)]
    op = np.clip(np.asarray(opacity, np.float64), 1e-6, 1 - 1e-6)
    cols = np.concatenate([means, (np.asarray(rgb) - 0.5) / SH_C0, np.log(op / (1 - op))[:, None], np.log(scales), quats], 1)
    vert = np.empty(len(cols), dtype=[(p, "f4") for p in props])
    for i, p in enumerate(props):
        vert[p] = cols[:, i]
    K = np.array([focal_px, 0, width / 2, 0, focal_px, height / 2, 0, 0, 1], np.float32)
    els = [PlyElement.describe(vert, "vertex"),
           PlyElement.describe(np.array([(k,) for k in K], dtype=[("intrinsic", "f4")]), "intrinsic"),
           PlyElement.describe(np.array([(width,), (height,)], dtype=[("image_size", "u4")]), "image_size")]  # fmt: skip
    PlyData(els).write(str(path))
    return Path(path)


def sharp_scene_in(scene: SharpScene, camera: Camera) -> tuple[torch.Tensor, torch.Tensor]:
    """The scene's means ``[N,3]`` and covariances ``[N,3,3]`` in the frame of ``camera`` (the main camera, whose
    camera frame is the world): the linear map ``A`` with ``project(camera, A x) = project(SHARP's camera, x)``
    for every point ``x`` (focal lengths and principal points differ; depth is kept)."""
    fs, sx, sy = scene.focal_px, camera.width / scene.width, camera.height / scene.height
    A = torch.tensor([[fs * sx / camera.fx, 0.0, (0.5 * camera.width - camera.cx) / camera.fx],
                      [0.0, fs * sy / camera.fy, (0.5 * camera.height - camera.cy) / camera.fy],
                      [0.0, 0.0, 1.0]])  # fmt: skip
    return scene.means @ A.T, A @ scene.covs @ A.T


def cone_cameras(main: Camera, pivot_depth: float, n_views: int, angle_deg: float) -> list[Camera]:
    """``n_views`` cameras around ``main`` (camera frame = world): each turned by ``angle_deg`` about the point
    at ``pivot_depth`` on the main axis, in directions evenly spread in azimuth (the first to the right),
    looking at that point with the main camera's intrinsics (module docstring).

    Raises:
        ValueError: if ``n_views < 1``, ``pivot_depth <= 0`` or ``angle_deg`` not in (0, 90).
    """
    if n_views < 1 or not pivot_depth > 0 or not 0 < angle_deg < 90:
        raise ValueError(f"need n_views >= 1, pivot_depth > 0 and 0 < angle_deg < 90, got {n_views}, {pivot_depth}, {angle_deg}")
    pivot = np.array([0.0, 0.0, pivot_depth])
    a = math.radians(angle_deg)
    cams = []
    for k in range(n_views):
        phi = 2 * math.pi * k / n_views
        eye = pivot + pivot_depth * np.array([math.sin(a) * math.cos(phi), math.sin(a) * math.sin(phi), -math.cos(a)])
        c = look_at(eye, pivot, (0.0, -1.0, 0.0), main.width, main.height)
        cams.append(Camera(main.width, main.height, main.fx, main.fy, main.cx, main.cy, c.R, c.t))
    return cams


def render_scene(means: torch.Tensor, covs: torch.Tensor, colors: torch.Tensor, opacities: torch.Tensor, camera: Camera,
                 backend: str = "auto") -> np.ndarray:  # fmt: skip
    """uint8 ``[H,W,3]`` image of 3-D Gaussians seen by ``camera``: EWA projection, primitives behind the near
    plane dropped, front-to-back compositing on black (the decoder's rule, :mod:`lagsplat.render.rasterize`)."""
    with torch.no_grad():
        uv, cov2, depth = project_gaussians(means, covs, camera)
        keep = depth > 1e-3
        uv, cov2, depth, op, col = uv[keep][None], cov2[keep], depth[keep][None], opacities[keep][None], colors[keep][None]
        uv, cov2, op, col, _ = depth_order(depth, uv, cov2[None], op, col)
        img = rasterize(uv, cov2, op, col, camera.height, camera.width, backend=backend)[0]
    return (img.clamp(0, 1).permute(1, 2, 0).cpu().numpy() * 255 + 0.5).astype(np.uint8)


def sharp_views(clip: Clip, exe: str, settings: Mapping[str, Any]) -> tuple[np.ndarray, list[Camera]]:
    """Run SHARP (``exe predict -i <frames> -o <scenes> -c <checkpoint>``) on every frame of ``clip`` and render
    each scene from the cone cameras (``n_views``, default 8; ``angle_deg``, default 10; module docstring).

    Returns:
        ``(images uint8 [T,M,H,W,3], cameras)``: the main camera first, then the ``M`` view cameras.

    Raises:
        ClipError: if the command fails (its last output lines quoted), or a frame's PLY is missing or malformed.
    """
    import cv2

    n_views, angle = int(settings.get("n_views") or 8), float(settings.get("angle_deg") or 10.0)
    H, W = clip.images.shape[1:3]
    with tempfile.TemporaryDirectory(prefix="lagsplat-sharp-") as tmp:
        src, out = Path(tmp) / "frames", Path(tmp) / "scenes"
        src.mkdir()
        for i, frame in enumerate(clip.images):
            cv2.imwrite(str(src / f"{i:06d}.png"), frame[:, :, ::-1])
        cmd = [exe, "predict", "-i", str(src), "-o", str(out), "-c", str(settings["checkpoint"])]
        r = subprocess.run(cmd, capture_output=True, text=True)
        if r.returncode != 0:
            tail = " | ".join((r.stderr or r.stdout).strip().splitlines()[-3:])
            raise ClipError(f"{exe}: 'sharp predict' failed (exit {r.returncode}): {tail}")
        first = read_sharp_ply(out / "000000.ply")
        main = Camera(W, H, first.focal_px * W / first.width, first.focal_px * H / first.height, W / 2.0, H / 2.0,
                      ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)), (0.0, 0.0, 0.0))  # fmt: skip
        views = cone_cameras(main, float(first.means[:, 2].median()), n_views, angle)
        images = np.empty((len(clip.images), n_views, H, W, 3), np.uint8)
        for i in range(len(clip.images)):
            scene = first if i == 0 else read_sharp_ply(out / f"{i:06d}.ply")
            means, covs = sharp_scene_in(scene, main)
            for m, cam in enumerate(views):
                images[i, m] = render_scene(means, covs, scene.colors, scene.opacities, cam, str(settings.get("backend") or "auto"))
    return images, [main, *views]
