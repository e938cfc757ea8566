"""Cached novel views of every frame of a clip, for Stage 1 under multi-view supervision (paper §3.2, App. C).

The paper supervises its 3-D reconstructions with views of each frame from other viewpoints, computed once
and cached (App. C: 65 SHARP renders per frame). The ``views`` stage writes them to ``<system>/views/``:

* ``views.npz``: ``images`` uint8 ``[T,M,H,W,3]`` (frame ``i`` of the clip seen by view camera ``m``) and
  ``key``, the cache key below;
* ``cameras.json``: ``M + 1`` cameras (:mod:`lagsplat.render.camera` records), the clip's main camera first
  (adjusted to the clip's crop and resize), then the ``M`` view cameras;
* ``views.json``: the source settings, the views held out of training (``holdout``, indices into the ``M``
  views: never used by Stage 1, scored as novel views) and ``key``, a SHA-256 of the clip's frames and
  timestamps, the settings and the bytes of every source file. :func:`ensure_views` recomputes only when
  the key changes; it reads the key from ``views.npz`` (and rewrites a missing ``views.json`` from it). The
  Snakemake rule declares the whole folder, which Snakemake removes before it reruns the job: the cache
  serves runs of the stage outside Snakemake.

View sources (``system.views.source``):

* ``synthetic``: ground-truth renders of a test scene from extra cameras (``path``: an NPZ with ``images
  [T0,M,H,W,3]`` and ``t [T0]``; ``cameras``: a JSON of ``M + 1`` cameras, main first), e.g.
  :mod:`lagsplat.synth.pendulum3d`;
* ``cameras``: real synchronised extra cameras (``videos``: one file per camera; ``calibration``: JSON of
  ``M + 1`` cameras, main first; ``fps``: their capture rate if the containers' is wrong), read with the
  same timing rules as the main clip (:func:`lagsplat.io.video.read_video`);
* ``sharp``: Apple's single-image view synthesis (a local installation: the ``sharp`` command and
  ``checkpoint``, the weights; it needs a GPU): each frame's regressed 3-D Gaussians rendered from ``n_views``
  cameras on a cone of half-angle ``angle_deg`` around the main camera (:mod:`lagsplat.views_sharp`). It is
  never needed by the tests; when absent the stage stops with one line naming what is missing.

Every view frame is matched to the clip frame of the same time (timestamps zeroed at the clip's first frame,
``system.frames``); a view without a frame within a quarter of a frame period stops with the file named.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from lagsplat.io.atomic import write_json, write_npz
from lagsplat.io.clip import Clip, ClipError
from lagsplat.io.common import jsonable
from lagsplat.render.camera import Camera, load_cameras, save_cameras

__all__ = ["VIEW_SOURCES", "ViewSet", "view_key", "build_views", "save_views", "load_views", "ensure_views", "main_camera_of", "scene_center", "scene_depth_range", "rig_depth", "static_stereo_depth",
           "plane_sweep_depth"]

VIEW_SOURCES = ("synthetic", "cameras", "sharp")
"""The view sources ``system.views.source`` selects (module docstring)."""

_FILE_KEYS = ("path", "cameras", "calibration", "videos", "checkpoint")


@dataclass
class ViewSet:
    """The cached views of a clip (module docstring).

    Attributes:
        images: uint8 ``[T,M,H,W,3]``, frame ``i`` seen by view camera ``m``.
        cameras: ``M + 1`` cameras, the main camera first.
        holdout: indices into the ``M`` views never used for training.
        key: the cache key (:func:`view_key`).
        settings: the source settings.
    """

    images: np.ndarray
    cameras: list[Camera]
    holdout: list[int] = field(default_factory=list)
    key: str = ""
    settings: dict = field(default_factory=dict)

    @property
    def n_views(self) -> int:
        """``M``, the number of view cameras (the main camera not counted)."""
        return int(self.images.shape[1])

    @property
    def train_views(self) -> list[int]:
        """Indices of the views Stage 1 trains on."""
        return [m for m in range(self.n_views) if m not in self.holdout]


def view_key(clip: Clip, settings: Mapping[str, Any]) -> str:
    """SHA-256 of the clip's frames and timestamps, the settings and the bytes of every source file they name."""
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(clip.images).tobytes())
    h.update(np.ascontiguousarray(clip.t).tobytes())
    h.update(json.dumps(jsonable(dict(settings)), sort_keys=True).encode())
    for k in _FILE_KEYS:
        v = settings.get(k)
        for p in ([v] if isinstance(v, str) else list(v or [])):
            path = Path(p)
            if path.is_file():
                with open(path, "rb") as fh:
                    for chunk in iter(lambda: fh.read(1 << 22), b""):
                        h.update(chunk)
    return h.hexdigest()


def main_camera_of(camera: Camera, clip: Clip) -> Camera:
    """The main camera as the clip sees it: shifted by the clip's crop (``meta["crop"] = [x0, y0, x1, y1]``) and
    scaled to its stored size.

    Raises:
        ClipError: if the camera's image size is not the clip's original size.
    """
    meta = clip.meta or {}
    orig = meta.get("original_size") or [camera.width, camera.height]
    if None not in orig and [int(orig[0]), int(orig[1])] != [camera.width, camera.height]:
        raise ClipError(f"main camera images {camera.width}x{camera.height} px, the clip's source {orig[0]}x{orig[1]}")
    crop = meta.get("crop")
    if crop:
        x0, y0, x1, y1 = (int(v) for v in crop)
        camera = Camera(x1 - x0, y1 - y0, camera.fx, camera.fy, camera.cx - x0, camera.cy - y0, camera.R, camera.t)
    H, W = clip.images.shape[1:3]
    return camera.resized(W, H)


def _align(t_views: np.ndarray, clip: Clip, source: str) -> np.ndarray:
    """Index into ``t_views`` of each clip frame (module docstring)."""
    start = int((clip.meta.get("frames") or [0])[0] or 0)
    if start >= len(t_views):
        raise ClipError(f"{source}: {len(t_views)} frames, the clip starts at frame {start}")
    tv = np.asarray(t_views, np.float64) - float(t_views[start])
    j = np.clip(np.searchsorted(tv, clip.t), 1, len(tv) - 1)
    j = np.where(np.abs(tv[j - 1] - clip.t) <= np.abs(tv[j] - clip.t), j - 1, j)
    tol = 0.25 * float(np.median(np.diff(clip.t))) if len(clip.t) > 1 else 1e-6
    bad = np.flatnonzero(np.abs(tv[j] - clip.t) > tol)
    if len(bad):
        raise ClipError(f"{source}: no view frame within {tol * 1e3:.1f} ms of clip frame {int(bad[0])} (t = {clip.t[bad[0]]:.3f} s)")
    return j


def _cameras(path: str, n_views: int) -> list[Camera]:
    cams = load_cameras(path)
    if len(cams) != n_views + 1:
        raise ClipError(f"{path}: {len(cams)} cameras for {n_views} views; need {n_views + 1} (the main camera first)")
    return cams


def _synthetic(clip: Clip, s: Mapping[str, Any]) -> tuple[np.ndarray, list[Camera]]:
    path = Path(str(s.get("path") or ""))
    if not path.is_file():
        raise ClipError(f"{path}: views file not found (system.views.path)")
    try:
        with np.load(path) as z:
            images, t = z["images"], z["t"]
    except (OSError, KeyError, ValueError) as e:
        raise ClipError(f"{path}: cannot read views (need images [T,M,H,W,3] uint8 and t [T]): {e}") from e
    if images.ndim != 5 or images.shape[-1] != 3 or images.dtype != np.uint8 or len(t) != len(images):
        raise ClipError(f"{path}: views must be uint8 [T,M,H,W,3] with t [T], got {images.dtype} {images.shape} and t {np.shape(t)}")
    cams = _cameras(str(s.get("cameras")), images.shape[1])
    return images[_align(t, clip, str(path))], cams


def _real_cameras(clip: Clip, s: Mapping[str, Any]) -> tuple[np.ndarray, list[Camera]]:
    from lagsplat.io.video import read_video

    videos = [str(v) for v in (s.get("videos") or [])]
    if not videos:
        raise ClipError("system.views.videos lists no extra camera (source: cameras)")
    cams = _cameras(str(s.get("calibration")), len(videos))
    out = []
    for v, cam in zip(videos, cams[1:]):
        frames, t, _ = read_video(v, fps=s.get("fps"))
        if frames.shape[1:3] != (cam.height, cam.width):
            raise ClipError(f"{v}: frames of {frames.shape[2]}x{frames.shape[1]} px, its calibration says {cam.width}x{cam.height}")
        out.append(frames[_align(t, clip, v)])
    if len({f.shape for f in out}) > 1:
        raise ClipError(f"{', '.join(videos)}: the extra cameras must share one image size, got {sorted({f.shape[1:3] for f in out})}")
    return np.stack(out, 1), cams


def _sharp(clip: Clip, s: Mapping[str, Any]) -> tuple[np.ndarray, list[Camera]]:
    exe = shutil.which(str(s.get("command") or "sharp"))
    if exe is None:
        raise ClipError("views.source=sharp needs Apple's SHARP installed (the 'sharp' command on PATH, a CUDA GPU); "
                        "use source=cameras or synthetic without it")  # fmt: skip
    ckpt = s.get("checkpoint")
    if not ckpt or not Path(str(ckpt)).is_file():
        raise ClipError(f"views.source=sharp needs its weights: system.views.checkpoint={ckpt!r} is not a file")
    from lagsplat.views_sharp import sharp_views

    return sharp_views(clip, exe, s)


_SOURCES = {"synthetic": _synthetic, "cameras": _real_cameras, "sharp": _sharp}


def build_views(clip: Clip, settings: Mapping[str, Any]) -> ViewSet:
    """Compute the views of ``clip`` from the source ``settings`` (``system.views``; module docstring).

    Raises:
        ClipError: for an unknown source, a missing or malformed source file (named), views that do not
            match the clip's frames in time, or a ``holdout`` index out of range.
    """
    s = dict(settings)
    source = s.get("source")
    if source not in _SOURCES:
        raise ClipError(f"system.views.source must be one of {list(VIEW_SOURCES)}, got {source!r}")
    images, cams = _SOURCES[source](clip, s)
    if source != "sharp":  # SHARP regresses its scenes from the stored frames: its main camera is already the clip's
        cams = [main_camera_of(cams[0], clip), *cams[1:]]
    holdout = [int(m) for m in (s.get("holdout") or [])]
    if any(not 0 <= m < images.shape[1] for m in holdout) or len(set(holdout)) == images.shape[1]:
        raise ClipError(f"system.views.holdout {holdout}: indices must lie in [0, {images.shape[1]}) and leave a view to train on")
    return ViewSet(np.ascontiguousarray(images), cams, holdout, view_key(clip, s), s)


def save_views(folder: str | Path, views: ViewSet) -> Path:
    """Write ``views.npz``, ``cameras.json`` and, last, ``views.json`` (module docstring) into ``folder``, atomically each."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    write_npz(folder / "views.npz", images=views.images, key=np.array(views.key))
    save_cameras(folder / "cameras.json", views.cameras)
    _write_index(folder, views.key, views.holdout, views.images.shape, views.settings)
    return folder


def _write_index(folder: Path, key: str, holdout: list[int], shape: tuple[int, ...], settings: Mapping[str, Any]) -> None:
    write_json(folder / "views.json", {"key": key, "holdout": holdout, "n_views": int(shape[1]), "size": [int(s) for s in shape[2:4]],
                                       "settings": jsonable(dict(settings))})  # fmt: skip


def load_views(folder: str | Path) -> ViewSet:
    """Read the views written by :func:`save_views`.

    Raises:
        FileNotFoundError: naming the folder, if the views were never computed.
        ClipError: naming the file, if one is unreadable or they disagree.
    """
    folder = Path(folder)
    if not (folder / "views.json").is_file():
        raise FileNotFoundError(f"{folder}: no cached views (run the views stage: python -m lagsplat views system=...)")
    try:
        info = json.loads((folder / "views.json").read_text())
        with np.load(folder / "views.npz") as z:
            images = z["images"]
    except (OSError, KeyError, ValueError) as e:
        raise ClipError(f"{folder}: cannot read the cached views ({e})") from e
    cams = load_cameras(folder / "cameras.json")
    if len(cams) != images.shape[1] + 1:
        raise ClipError(f"{folder / 'cameras.json'}: {len(cams)} cameras for {images.shape[1]} views")
    return ViewSet(images, cams, list(info.get("holdout", [])), str(info.get("key", "")), dict(info.get("settings", {})))


def ensure_views(folder: str | Path, clip: Clip, settings: Mapping[str, Any]) -> tuple[ViewSet, bool]:
    """The cached views in ``folder`` if their key matches ``clip`` and ``settings``, else freshly built and saved.

    Returns:
        ``(views, computed)``, ``computed`` False when the cache was used.
    """
    folder = Path(folder)
    key = None
    if (folder / "views.npz").is_file():
        try:
            with np.load(folder / "views.npz") as z:
                key = str(z["key"]) if "key" in z.files else None
        except (OSError, ValueError):
            key = None
    if key is not None and key == view_key(clip, settings) and (folder / "cameras.json").is_file():
        if not (folder / "views.json").is_file():  # the index alone was removed: rewrite it
            with np.load(folder / "views.npz") as z:
                shape = z["images"].shape
            _write_index(folder, key, [int(m) for m in (settings.get("holdout") or [])], shape, settings)
        return load_views(folder), False
    views = build_views(clip, settings)
    save_views(folder, views)
    return views, True


def scene_center(cameras: list[Camera]) -> np.ndarray:
    """The world point ``[3]`` nearest to every camera's optical axis (least squares): where a rig looks.

    Raises:
        ValueError: with fewer than two cameras.
    """
    if len(cameras) < 2:
        raise ValueError("the scene centre needs at least two cameras")
    A, b = np.zeros((3, 3)), np.zeros(3)
    for c in cameras:
        axis = np.asarray(c.R, float)[2]
        P = np.eye(3) - np.outer(axis, axis)
        A += P
        b += P @ c.center
    return np.linalg.lstsq(A, b, rcond=None)[0]


def scene_depth_range(cameras: list[Camera], spread: float = 0.5) -> tuple[float, float]:
    """Depths ``(near, far)`` along the main camera to place new primitives at: the main camera's depth ``D`` of
    :func:`scene_center`, times ``1 -+ spread``.

    Raises:
        ValueError: with fewer than two cameras, or axes that do not meet in front of the main camera.
    """
    X = scene_center(cameras)
    main = cameras[0]
    D = float(np.asarray(main.R, float)[2] @ X + np.asarray(main.t, float)[2])
    if not D > 0:
        raise ValueError(f"the cameras' axes meet behind the main camera (depth {D:.3g})")
    return D * (1.0 - spread), D * (1.0 + spread)


def plane_sweep_depth(images: np.ndarray, cameras: list[Camera], ref: int, depth_range: tuple[float, float], n_depths: int = 48,
                      window: int = 5) -> np.ndarray:  # fmt: skip
    """Depth map ``[H,W]`` (world units along camera ``ref``'s axis) of one instant seen by several cameras: plane-sweep
    multi-view stereo (Collins 1996). For each of ``n_depths`` depths, even in inverse depth over ``depth_range``,
    every pixel of camera ``ref`` is back-projected, projected into the other cameras and compared with what they
    see there (mean absolute colour difference over the cameras that see the point, averaged over a
    ``window x window`` box); each pixel takes the depth of least cost.

    Args:
        images: uint8 ``[C,H,W,3]``, the same instant seen by the ``C`` cameras (sizes may differ only if passed
            as a list).
        cameras: the ``C`` cameras.
        ref: index of the camera whose depth map is wanted.
        depth_range: ``(near, far)``, world units.

    Raises:
        ValueError: with fewer than two cameras, or a depth range that is not ``0 < near < far``.
    """
    import torch
    import torch.nn.functional as F

    from lagsplat.render.camera import project_points

    if len(cameras) < 2 or len(images) != len(cameras):
        raise ValueError(f"plane sweep needs one image per camera and at least two cameras, got {len(images)} and {len(cameras)}")
    near, far = (float(v) for v in depth_range)
    if not 0 < near < far:
        raise ValueError(f"depth_range must satisfy 0 < near < far, got {depth_range}")
    imgs = [torch.from_numpy(np.ascontiguousarray(im)).permute(2, 0, 1).float()[None] / 255.0 for im in images]
    H, W = imgs[ref].shape[2:]
    cam = cameras[ref].resized(W, H)
    ys, xs = torch.meshgrid(torch.arange(H) + 0.5, torch.arange(W) + 0.5, indexing="ij")
    uv = torch.stack([xs, ys], -1).reshape(-1, 2)
    depths = 1.0 / torch.linspace(1.0 / near, 1.0 / far, n_depths)
    cost = torch.empty(n_depths, H, W)
    for k, dep in enumerate(depths):
        X = cam.unproject(uv, dep.expand(len(uv)))
        total, seen = torch.zeros(H * W), torch.zeros(H * W)
        for c, (img, other) in enumerate(zip(imgs, cameras)):
            if c == ref:
                continue
            h, w = img.shape[2:]
            p, z = project_points(X, other.resized(w, h))
            grid = torch.stack([2 * p[:, 0] / w - 1, 2 * p[:, 1] / h - 1], -1)
            inside = (grid.abs() <= 1).all(-1) & (z > 0)
            col = F.grid_sample(img, grid[None, None], align_corners=False)[0, :, 0]  # [3, HW]
            total += torch.where(inside, (col - imgs[ref].reshape(3, -1)).abs().mean(0), torch.zeros(()))
            seen += inside.float()
        c_k = torch.where(seen > 0, total / seen.clamp_min(1), torch.full_like(total, 1.0)).reshape(1, 1, H, W)
        cost[k] = F.avg_pool2d(F.pad(c_k, (window // 2,) * 4, mode="replicate"), window, 1)[0, 0]
    return depths[cost.argmin(0)].numpy()


def rig_depth(frames: np.ndarray, views: ViewSet, train_idx: np.ndarray, j: int, c: int, depth_range: tuple[float, float]) -> np.ndarray:
    """The plane-sweep depth ``[h,w]`` (:func:`plane_sweep_depth`) of camera ``c`` of the training rig (0: the main
    camera, then ``views.train_views``) at training frame ``j`` (``frames [N,H,W,3]`` the main camera's training
    frames, ``train_idx [N]`` their clip frames)."""
    rig = list(views.train_views)
    images = np.concatenate([frames[j : j + 1], views.images[train_idx[j], rig]])
    return plane_sweep_depth(images, [views.cameras[0]] + [views.cameras[1 + m] for m in rig], c, depth_range)


def static_stereo_depth(frames: np.ndarray, views: ViewSet, train_idx: np.ndarray, depth_range: tuple[float, float], n_frames: int = 8) -> list[tuple]:
    """Depth targets of the static scene for every camera of the training rig (the main camera, then
    ``views.train_views``): the per-pixel median over ``n_frames`` training instants of the plane-sweep depth
    (:func:`plane_sweep_depth`), and a mask of the pixels where it is trusted, those that stay still over the
    training frames (temporal spread below three times the image's median spread, or 2 grey levels) and carry texture (the
    gradient of the median image above its median: plane sweep cannot place a flat colour).

    Args:
        frames: uint8 ``[N,H,W,3]``, the main camera's training frames.
        views: the clip's views; ``train_idx [N]`` the clip frames of ``frames``.
        depth_range: ``(near, far)``, world units.

    Returns:
        per rig camera ``(depth [h,w] float32 tensor, world units; mask [h,w] bool tensor)``.
    """
    import torch

    rig_views = list(views.train_views)
    pick = np.unique(np.linspace(0, len(frames) - 1, min(n_frames, len(frames))).round().astype(int))
    out = []
    for c in range(1 + len(rig_views)):
        seq = frames if c == 0 else views.images[train_idx, rig_views[c - 1]]  # [N,h,w,3] this camera's training frames
        D = np.median([rig_depth(frames, views, train_idx, j, c, depth_range) for j in pick], axis=0)
        spread = seq.astype(np.float32).std(0).mean(-1)
        med = np.median(seq, axis=0).astype(np.float32).mean(-1)
        grad = np.hypot(*np.gradient(med))
        mask = (spread < max(3.0 * float(np.median(spread)), 2.0)) & (grad > np.median(grad))
        out.append((torch.from_numpy(D.astype(np.float32)), torch.from_numpy(mask)))
    return out
