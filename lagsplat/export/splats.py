"""The decoder at chosen states as standard 3-D Gaussian splatting ``.ply`` files (paper §3.2, Eq. 2-4).

Slicing the conditioned decoder at a state ``q`` (``z = q W^-1 + mean``, the chart's de-whitening) gives
ordinary Gaussians: centres ``mu_k(q)`` (Schur mean, Eq. 2), covariances (Schur complement, Eq. 3) and
opacities ``alpha_k`` times the latent gate (Eq. 4). They are written in the vertex layout of the INRIA
3-D Gaussian splatting code: ``x, y, z, nx, ny, nz, f_dc_0..2, f_rest_0..44, opacity, scale_0..2, rot_0..3``
(float32, binary little-endian), with

* colours as degree-0 spherical harmonics, ``f_dc = (rgb - 0.5) / SH_C0``, and the 45 higher-degree
  coefficients of a degree-3 file zero (so loaders that expect degree 3, the INRIA default, read them);
* opacity as a logit, scales as the log standard deviations along the principal axes, ``rot`` the unit
  quaternion ``(w, x, y, z)`` of the principal axes (``Sigma = R diag(exp(scale))^2 R^T``);
* normals zero.

The 2-D decoder is placed in the image plane in pixels of the training resolution (``x`` right, ``y``
down), with a thin standard deviation :data:`THIN_PX` across it. It composites its Gaussians front to back
in index order (:mod:`lagsplat.render.rule`), which a viewer that sorts by depth cannot know on one plane:
Gaussian ``k`` sits at ``z = k`` :data:`DEPTH_STEP_PX`, so seen from ``z < 0`` looking along ``+z`` (any
standard viewer's depth sort) the order, and the picture, are the decoder's. The 3-D decoder stays in its world units
(OpenCV axes, x right, y down, z forward). A 2-D decoder's static layer (``backdrop``) is not a Gaussian
and is not in the files.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from lagsplat.io.atomic import atomic_write
from lagsplat.models.decoder import ConditionedGaussians
from lagsplat.views_sharp import SH_C0

__all__ = ["PLY_FIELDS", "N_SH_REST", "THIN_PX", "DEPTH_STEP_PX", "SplatSet", "splat_states", "splats_at", "covariance_to_scale_rotation", "write_splat_ply", "read_ply_vertices"]

N_SH_REST = 45
"""Higher-degree spherical-harmonic coefficients of a degree-3 INRIA file (``3 ((3 + 1)^2 - 1)``), written as zeros."""

PLY_FIELDS = ("x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", *(f"f_rest_{i}" for i in range(N_SH_REST)),
              "opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3")  # fmt: skip
"""The INRIA 3-D Gaussian splatting vertex properties, in file order (all float32)."""

THIN_PX = 0.01
"""Standard deviation across the image plane (pixels) of a 2-D decoder's Gaussians."""

DEPTH_STEP_PX = 1e-3
"""Depth between consecutive Gaussians of a 2-D decoder (pixels): the compositing order as a depth order."""

SplatSet = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]
"""``(means [K,3], covariances [K,3,3], rgb [K,3] in [0, 1], opacity [K] in [0, 1])``."""


def splat_states(q: np.ndarray) -> list[tuple[str, np.ndarray]]:
    """The states to export: the chart's mean, then its min and max along each coordinate (others at the mean).

    Args:
        q: ``[T,d]`` encoded chart trajectory.

    Returns:
        ``[(label, q [d])]``, ``2 d + 1`` entries: ``"mean"``, ``"q_1=min"``, ``"q_1=max"``, ...
    """
    q = np.asarray(q, np.float64)
    mean = q.mean(0)
    out = [("mean", mean)]
    for i in range(q.shape[1]):
        for label, v in (("min", q[:, i].min()), ("max", q[:, i].max())):
            s = mean.copy()
            s[i] = v
            out.append((f"q_{i + 1}={label}", s))
    return out


@torch.no_grad()
def splats_at(decoder: ConditionedGaussians, z: np.ndarray, height: int, width: int) -> SplatSet:
    """The decoder's Gaussians sliced at the raw latent ``z [d]`` (paper Eq. 2-4), as 3-D Gaussians.

    Args:
        decoder: a 2-D (:class:`ConditionedGaussians`) or 3-D conditioned decoder.
        z: ``[d]`` raw latent (``Chart.to_raw`` of a chart state).
        height, width: the training resolution, pixels (the 2-D decoder's units).

    Returns:
        :data:`SplatSet`; 2-D: means in pixels, Gaussian ``k`` at depth ``z = k DEPTH_STEP_PX`` (the decoder's
        front-to-back order), covariances in px^2 with :data:`THIN_PX` across.

    Raises:
        ValueError: for a decoder that is not a conditioned-Gaussian one (e.g. the deformation decoder).
    """
    if decoder.kind not in ("conditioned", "conditioned3d"):
        raise ValueError(f"the {decoder.kind!r} decoder has no conditioned Gaussians to export as .ply")
    zt = torch.as_tensor(np.asarray(z, np.float64), dtype=torch.float32)[None]
    means, gate, g = decoder.condition(zt)
    means, cov = means[0].double().numpy(), g.cov.double().numpy()
    opacity = (g.alpha[None] * gate)[0].double().numpy()
    rgb = g.colors.double().numpy()
    if decoder.n_space == 2:
        s = np.array([float(width), float(height)])
        K = len(means)
        means = np.concatenate([means * s, DEPTH_STEP_PX * np.arange(K, dtype=np.float64)[:, None]], 1)
        cov3 = np.zeros((K, 3, 3))
        cov3[:, :2, :2] = cov * s[None, :, None] * s[None, None, :]
        cov3[:, 2, 2] = THIN_PX**2
        cov = cov3
    return means, cov, rgb, opacity


def _rotation_to_quaternion(R: np.ndarray) -> np.ndarray:
    """Unit quaternions ``[K,4]`` ``(w, x, y, z)`` of rotation matrices ``R [K,3,3]`` (largest-component branch)."""
    K = len(R)
    q = np.zeros((K, 4))
    tr = np.trace(R, axis1=1, axis2=2)
    diag = np.stack([R[:, 0, 0], R[:, 1, 1], R[:, 2, 2]], 1)
    cand = np.concatenate([tr[:, None], diag], 1)
    pick = cand.argmax(1)
    for k in range(K):
        r, p = R[k], pick[k]
        if p == 0:
            s = 2.0 * np.sqrt(max(1.0 + tr[k], 1e-300))
            q[k] = [0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s]
        else:
            i = p - 1
            j, m = (i + 1) % 3, (i + 2) % 3
            s = 2.0 * np.sqrt(max(1.0 + r[i, i] - r[j, j] - r[m, m], 1e-300))
            v = np.zeros(3)
            v[i] = 0.25 * s
            v[j] = (r[j, i] + r[i, j]) / s
            v[m] = (r[m, i] + r[i, m]) / s
            q[k] = [(r[m, j] - r[j, m]) / s, *v]
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)  # w >= 0: one of the two quaternions of each rotation
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def covariance_to_scale_rotation(cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Principal axes of covariances ``cov [K,3,3]``: ``(std [K,3], quaternion [K,4] (w, x, y, z))`` with
    ``cov = R diag(std)^2 R^T``, ``R`` the quaternion's rotation (a proper rotation, det +1)."""
    lam, R = np.linalg.eigh(0.5 * (cov + np.swapaxes(cov, 1, 2)))
    R = R * np.where(np.linalg.det(R) < 0, -1.0, 1.0)[:, None, None]  # flip all axes of an improper frame
    return np.sqrt(np.clip(lam, 1e-30, None)), _rotation_to_quaternion(R)


def write_splat_ply(path: str | Path, splats: SplatSet) -> Path:
    """Write ``splats`` (:data:`SplatSet`) as a binary little-endian ``.ply`` in the layout :data:`PLY_FIELDS`, atomically.

    Returns:
        ``path``.
    """
    means, cov, rgb, opacity = splats
    std, quat = covariance_to_scale_rotation(np.asarray(cov, np.float64))
    op = np.clip(np.asarray(opacity, np.float64), 1e-6, 1.0 - 1e-6)
    K = len(means)
    cols = np.concatenate([np.asarray(means, np.float64), np.zeros((K, 3)), (np.asarray(rgb, np.float64) - 0.5) / SH_C0,
                           np.zeros((K, N_SH_REST)), np.log(op / (1.0 - op))[:, None], np.log(std), quat], 1)  # fmt: skip
    vert = np.empty(K, dtype=[(f, "<f4") for f in PLY_FIELDS])
    for i, f in enumerate(PLY_FIELDS):
        vert[f] = cols[:, i]
    header = "ply\nformat binary_little_endian 1.0\n" + f"element vertex {K}\n" + "".join(f"property float {f}\n" for f in PLY_FIELDS) + "end_header\n"
    with atomic_write(path) as tmp:
        tmp.write_bytes(header.encode("ascii") + vert.tobytes())
    return Path(path)


def read_ply_vertices(path: str | Path) -> np.ndarray:
    """The vertex table of a binary little-endian ``.ply`` whose properties are all ``float`` (as written by
    :func:`write_splat_ply`), as a structured array.

    Raises:
        ValueError: naming the file if its header is not of that kind or its body has the wrong size.
    """
    data = Path(path).read_bytes()
    end = data.find(b"end_header\n")
    if not data.startswith(b"ply\n") or end < 0:
        raise ValueError(f"{path}: not a PLY file")
    lines = data[:end].decode("ascii").splitlines()
    if "format binary_little_endian 1.0" not in lines:
        raise ValueError(f"{path}: not a binary little-endian PLY")
    n = next((int(ln.split()[2]) for ln in lines if ln.startswith("element vertex ")), None)
    props = [ln.split() for ln in lines if ln.startswith("property ")]
    if n is None or any(p[1] != "float" for p in props):
        raise ValueError(f"{path}: expected one vertex element of float properties")
    dtype = np.dtype([(p[2], "<f4") for p in props])
    body = data[end + len(b"end_header\n") :]
    if len(body) != n * dtype.itemsize:
        raise ValueError(f"{path}: {len(body)} bytes of vertex data, expected {n} x {dtype.itemsize}")
    return np.frombuffer(body, dtype=dtype, count=n)
