"""Pinhole cameras and the projection of 3-D Gaussians to the image plane (EWA splatting).

Conventions (OpenCV's): a camera maps a world point ``X`` to camera coordinates ``x_c = R X + t``
(``R``, ``t`` the world-to-camera extrinsics), x to the right, y down, z forward (the viewing direction);
pixel ``(u, v) = (f_x x_c / z_c + c_x, f_y y_c / z_c + c_y)`` in the pixel convention of
:mod:`lagsplat.render.rule` (pixel ``(i, j)`` has its centre at ``(j + 0.5, i + 0.5)``).

A 3-D Gaussian ``N(mu, Sigma)`` projects to the 2-D Gaussian of the first-order (EWA) approximation
(Zwicker et al. 2002; Kerbl et al. 2023, Eq. 5): mean ``pi(mu)``, covariance ``J W Sigma W^T J^T`` with
``W = R`` and ``J`` the Jacobian of the perspective map at the camera-space mean. The 2-D Gaussians then go
through the 2-D rasteriser front to back: :func:`depth_order` sorts them by camera depth, since the
rasteriser composites in index order.

Cameras are stored as JSON (:func:`save_cameras`, :func:`load_cameras`): a list of objects with
``width``, ``height`` (px), ``fx``, ``fy``, ``cx``, ``cy`` (px) and ``R`` (3x3, row-major) and ``t`` (3),
the world-to-camera extrinsics in the convention above, world units (metres for calibrated rigs).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import torch
from torch import Tensor

__all__ = ["Camera", "look_at", "orbit", "orbit_through", "project_points", "project_gaussians", "depth_order", "save_cameras", "load_cameras"]

#: Points closer than this to the camera plane (world units along z) are culled (their projection is unstable).
NEAR = 1e-3


@dataclass(frozen=True)
class Camera:
    """A pinhole camera: intrinsics ``fx, fy, cx, cy`` (px), image ``width x height`` (px) and world-to-camera
    extrinsics ``R [3,3]``, ``t [3]`` (module docstring).

    Raises:
        ValueError: on a non-positive focal length or image size, or an ``R`` that is not a rotation.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    R: tuple[tuple[float, float, float], ...]
    t: tuple[float, float, float]

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"camera image size must be positive, got {self.width}x{self.height}")
        if not (self.fx > 0 and self.fy > 0):
            raise ValueError(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy}")
        R = np.asarray(self.R, float)
        if R.shape != (3, 3) or np.abs(R @ R.T - np.eye(3)).max() > 1e-5 or np.linalg.det(R) < 0:
            raise ValueError(f"R must be a 3x3 rotation (orthonormal, det +1), got {R.tolist()}")
        if np.asarray(self.t, float).shape != (3,):
            raise ValueError(f"t must have 3 entries, got {self.t}")

    @property
    def K(self) -> np.ndarray:
        """Intrinsic matrix ``[3,3]``."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates ``[3]``: ``-R^T t``."""
        return -np.asarray(self.R, float).T @ np.asarray(self.t, float)

    def tensors(self, dtype: torch.dtype = torch.float32, device: torch.device | str | None = None) -> tuple[Tensor, Tensor]:
        """``(R [3,3], t [3])`` as tensors of ``dtype`` on ``device`` (default the CPU)."""
        return torch.as_tensor(self.R, dtype=dtype, device=device), torch.as_tensor(self.t, dtype=dtype, device=device)

    def resized(self, width: int, height: int) -> "Camera":
        """The same camera imaging ``width x height`` px (intrinsics scaled per axis; the identity at its own size)."""
        if (int(width), int(height)) == (self.width, self.height):
            return self
        sx, sy = width / self.width, height / self.height
        return Camera(int(width), int(height), self.fx * sx, self.fy * sy, self.cx * sx, self.cy * sy, self.R, self.t)

    def unproject(self, uv: Tensor, depth: Tensor) -> Tensor:
        """World points ``[...,3]`` seen at pixels ``uv [...,2]`` at camera depths ``depth [...]`` (world units along z)."""
        R, t = self.tensors(uv.dtype, uv.device)
        xc = torch.stack([(uv[..., 0] - self.cx) / self.fx * depth, (uv[..., 1] - self.cy) / self.fy * depth, depth], -1)
        return (xc - t) @ R

    def to_dict(self) -> dict:
        """The JSON record of this camera (module docstring)."""
        return {"width": int(self.width), "height": int(self.height), "fx": float(self.fx), "fy": float(self.fy), "cx": float(self.cx),
                "cy": float(self.cy), "R": [list(map(float, r)) for r in self.R], "t": list(map(float, self.t))}  # fmt: skip

    @classmethod
    def from_dict(cls, d: dict) -> "Camera":
        """A camera from its JSON record. Raises ``KeyError`` naming a missing field, ``ValueError`` as the constructor."""
        missing = [k for k in ("width", "height", "fx", "fy", "cx", "cy", "R", "t") if k not in d]
        if missing:
            raise KeyError(f"camera record lacks {missing}")
        return cls(int(d["width"]), int(d["height"]), float(d["fx"]), float(d["fy"]), float(d["cx"]), float(d["cy"]),
                   tuple(tuple(float(x) for x in r) for r in d["R"]), tuple(float(x) for x in d["t"]))  # fmt: skip


def look_at(eye: Sequence[float], target: Sequence[float], up: Sequence[float], width: int, height: int, fov_y_deg: float = 40.0) -> Camera:
    """A camera at ``eye`` looking at ``target`` with ``up`` towards the top of the image, vertical field of view
    ``fov_y_deg``, square pixels, principal point at the image centre.

    Raises:
        ValueError: if ``eye`` and ``target`` coincide or ``up`` is parallel to the viewing direction.
    """
    eye, target, up = (np.asarray(v, float) for v in (eye, target, up))
    z = target - eye
    if np.linalg.norm(z) < 1e-12:
        raise ValueError("look_at: eye and target coincide")
    z /= np.linalg.norm(z)
    y = -(up - (up @ z) * z)  # image y (down): against up, across the viewing direction
    if np.linalg.norm(y) < 1e-9:
        raise ValueError("look_at: up is parallel to the viewing direction")
    y /= np.linalg.norm(y)
    x = np.cross(y, z)  # right-handed: x = y cross z
    R = np.stack([x, y, z])
    f = 0.5 * height / math.tan(math.radians(fov_y_deg) / 2)
    return Camera(width, height, f, f, width / 2.0, height / 2.0, tuple(map(tuple, R)), tuple(-R @ eye))


def orbit(target: Sequence[float], radius: float, elevation_deg: float, n: int, width: int, height: int, up: Sequence[float] = (0.0, -1.0, 0.0),
          fov_y_deg: float = 40.0, azimuth0_deg: float = 0.0, azimuths_deg: Sequence[float] | None = None) -> list[Camera]:  # fmt: skip
    """``n`` cameras evenly spaced in azimuth on a circle of ``radius`` around ``target`` (about the ``up`` axis),
    raised by ``elevation_deg``, all looking at ``target``. The default ``up`` is world ``-y`` (a scene in the
    main camera's frame, y down). Azimuth 0 puts the camera on the world ``-z`` side of the target; with
    ``azimuths_deg`` the cameras stand at those azimuths (added to ``azimuth0_deg``) instead (``n`` unused)."""
    up_v, ref, side = _orbit_basis(up)
    el = math.radians(elevation_deg)
    cams = []
    offsets = [math.radians(a) for a in azimuths_deg] if azimuths_deg is not None else [2 * math.pi * k / n for k in range(n)]
    for off in offsets:
        az = math.radians(azimuth0_deg) + off
        d = math.cos(el) * (math.cos(az) * ref + math.sin(az) * side) + math.sin(el) * up_v
        cams.append(look_at(np.asarray(target, float) + radius * d, target, up_v, width, height, fov_y_deg))
    return cams


def _orbit_basis(up: Sequence[float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(up, ref, side)``: unit ``up``, azimuth 0 (world ``-z`` made perpendicular to ``up``, or ``+x``) and azimuth 90 degrees."""
    up_v = np.asarray(up, float) / np.linalg.norm(up)
    ref = np.array([0.0, 0.0, -1.0]) - up_v * -up_v[2]  # world -z, made perpendicular to up
    if np.linalg.norm(ref) < 1e-9:
        ref = np.array([1.0, 0.0, 0.0]) - up_v * up_v[0]
    ref /= np.linalg.norm(ref)
    return up_v, ref, np.cross(up_v, ref)


def _azimuth(camera: Camera, target: Sequence[float], point: np.ndarray) -> tuple[float, float, float]:
    """``(azimuth_deg, elevation_deg, radius)`` of ``point`` about ``target`` in the orbit basis of ``camera``'s image up."""
    up_v, ref, side = _orbit_basis(-np.asarray(camera.R, float)[1])  # image y points down
    offset = np.asarray(point, float) - np.asarray(target, float)
    radius = float(np.linalg.norm(offset))
    el = math.degrees(math.asin(float(np.clip(offset @ up_v / radius, -1.0, 1.0))))
    return math.degrees(math.atan2(float(offset @ side), float(offset @ ref))), el, radius


def orbit_through(camera: Camera, target: Sequence[float], n: int, width: int | None = None, height: int | None = None,
                  span: Sequence[Camera] | None = None) -> list[Camera]:  # fmt: skip
    """``n`` cameras on the orbit around ``target`` that passes through ``camera`` (its distance, elevation and field
    of view; up is the camera's image up, :func:`orbit`): the full circle from ``camera``'s own azimuth, or, with
    ``span``, there and back over the azimuths those cameras stand at (the side of the scene that was filmed)."""
    az0, el, radius = _azimuth(camera, target, camera.center)
    w, h = width or camera.width, height or camera.height
    fov = math.degrees(2 * math.atan(0.5 * camera.height / camera.fy))
    up = -np.asarray(camera.R, float)[1]
    if not span:
        return orbit(target, radius, el, n, w, h, up, fov, az0)
    rel = [(_azimuth(camera, target, c.center)[0] - az0 + 180.0) % 360.0 - 180.0 for c in [camera, *span]]
    lo, hi = min(rel), max(rel)
    ping = 0.5 - 0.5 * np.cos(np.linspace(0.0, 2 * math.pi, n, endpoint=False))  # 0 -> 1 -> 0, eased at the ends
    return orbit(target, radius, el, n, w, h, up, fov, az0, azimuths_deg=(lo + (hi - lo) * ping).tolist())


def _camera_space(X: Tensor, cam: Camera) -> tuple[Tensor, Tensor, Tensor]:
    """Camera coordinates ``x_c [...,3]``, pixels ``[...,2]`` (depth clamped at :data:`NEAR`) and depths ``z_c [...]``."""
    R, t = cam.tensors(X.dtype, X.device)
    xc = X @ R.T + t
    zs = xc[..., 2].clamp_min(NEAR)
    uv = torch.stack([cam.fx * xc[..., 0] / zs + cam.cx, cam.fy * xc[..., 1] / zs + cam.cy], -1)
    return xc, uv, xc[..., 2]


def project_points(X: Tensor, cam: Camera) -> tuple[Tensor, Tensor]:
    """Pixel positions ``[...,2]`` and camera depths ``z_c [...]`` of world points ``X [...,3]``."""
    _, uv, z = _camera_space(X, cam)
    return uv, z


def project_gaussians(mu: Tensor, cov: Tensor, cam: Camera) -> tuple[Tensor, Tensor, Tensor]:
    """EWA projection of 3-D Gaussians (module docstring).

    Args:
        mu: ``[...,3]`` world means.
        cov: ``[...,3,3]`` world covariances.
        cam: the camera.

    Returns:
        ``(means [...,2] px, covs [...,2,2] px^2, depth [...])``; a Gaussian behind the near plane has depth
        ``<= NEAR`` (cull it, e.g. with a zero opacity).
    """
    xc, uv, z = _camera_space(mu, cam)
    zs = z.clamp_min(NEAR)
    zero = torch.zeros_like(zs)
    J = torch.stack([torch.stack([cam.fx / zs, zero, -cam.fx * xc[..., 0] / zs**2], -1),
                     torch.stack([zero, cam.fy / zs, -cam.fy * xc[..., 1] / zs**2], -1)], -2)  # fmt: skip
    T = J @ cam.tensors(mu.dtype, mu.device)[0]
    cov2 = T @ cov @ T.transpose(-1, -2)
    return uv, 0.5 * (cov2 + cov2.transpose(-1, -2)), z


def depth_order(depth: Tensor, *per_gaussian: Tensor) -> tuple[Tensor, ...]:
    """Sort per-Gaussian tensors ``[B,K,...]`` front to back by ``depth [B,K]`` (stable: equal depths keep their
    index order), the order the 2-D rasteriser composites in. Returns the sorted tensors, then the ``[B,K]`` order."""
    order = torch.sort(depth, dim=-1, stable=True).indices
    out = []
    for x in per_gaussian:
        idx = order.reshape(order.shape + (1,) * (x.dim() - 2)).expand(order.shape + x.shape[2:])
        out.append(torch.gather(x, 1, idx))
    return (*out, order)


def save_cameras(path: str | Path, cameras: Sequence[Camera]) -> Path:
    """Write cameras as a JSON list (module docstring), atomically."""
    from lagsplat.io.atomic import write_json

    return write_json(path, [c.to_dict() for c in cameras])


def load_cameras(path: str | Path) -> list[Camera]:
    """Read a JSON list of cameras.

    Raises:
        ValueError: naming the file and the camera whose record is malformed or not a list.
    """
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise ValueError(f"{path}: cannot read cameras ({e})") from e
    if not isinstance(data, list):
        raise ValueError(f"{path}: expected a JSON list of cameras, got {type(data).__name__}")
    cams = []
    for i, d in enumerate(data):
        try:
            cams.append(Camera.from_dict(d))
        except (KeyError, ValueError, TypeError) as e:
            raise ValueError(f"{path}: camera {i}: {e}") from e
    return cams
