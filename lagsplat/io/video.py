"""Read a video file with OpenCV, with honest per-frame timestamps.

Frames are decoded with ``cv2.VideoCapture`` and converted from BGR to RGB.
Each frame's timestamp is the decoder's ``CAP_PROP_POS_MSEC`` read right after
the frame. Those raw timestamps then go through one timing rule (implemented
in :func:`lagsplat.io.timing.resolve_timing`):

* The container fps is *absurd* if not finite, ``<= 0``, ``< 1`` or
  ``> max_fps``; timestamps *jitter* if any interval is ``<= 0`` or
  ``std(dt) / mean(dt) > jitter_tol``.
* ``fps`` given (true capture rate, ``system.source.fps``): ``t_i = i / fps``;
  a warning naming the file is issued if the container fps is absurd, the
  timestamps jitter, or their mean rate differs from ``fps`` by more than 1 %.
* else, regular timestamps spanning ``> 0`` s are used (shifted to start at
  0), even if the container's nominal fps differs slightly (the ``.mov`` that
  says 59.77 fps but has frames exactly 16.683 ms apart gets its timestamps).
* else, jittering timestamps with a plausible container fps: warn and use
  uniform timestamps at the timestamps' mean rate ``(T-1) / (t_last - t_first)``.
* else (absurd container fps, jittering timestamps, no ``fps``): ClipError,
  e.g. ``oscillating_cart.webm: container claims 1000 fps and frame
  timestamps jitter (31-49 ms); state the true capture rate with
  system.source.fps=<Hz>``.

The rule always looks at *all* decoded frames, also when only a frame range
is kept.

Damaged files: a missing file, a file OpenCV cannot open (garbage bytes; an
MP4 cut short before its ``moov`` index, which FFmpeg cannot open at all) or
one that yields no frame raises ``ClipError("<path>: cannot decode video
(...)")``. A file that opens but ends early is decoded as far as possible; if
the container states a frame count and fewer than 90 % of it were decoded,
``ClipError("<path>: video is truncated or corrupt: decoded N of M frames")``
is raised; if fewer than stated but at least 90 % (more than 2 short), a
:class:`TruncatedVideoWarning` names the file and both counts. The count is the
one the container states, trusted only with a plausible container fps (see the
timing rule): where the container states no count, OpenCV estimates it as
duration x fps, which with an absurd fps (a WebM's 1000 fps time base) is
meaningless, e.g. 8066 frames for a 242-frame recording. Containers without a
(trusted) count, such as browser WebM, are checked by their structure instead
(:func:`matroska_ends_early`: a WebM / Matroska file whose last element runs
past its end was cut short) and warn the same way.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from lagsplat.io.common import FrameCollector, FrameTransform, check_range, cv_to_rgb, validate_range
from lagsplat.io.clip import ClipError
from lagsplat.io.timing import is_absurd_fps, resolve_timing

__all__ = ["read_video", "VIDEO_EXTENSIONS", "TruncatedVideoWarning", "matroska_ends_early"]

VIDEO_EXTENSIONS = (".mp4", ".webm", ".mov", ".avi", ".mkv", ".m4v")
"""File extensions (lower case) treated as video by :func:`lagsplat.ingest.ingest`."""

_OPEN_TIMEOUT_MS = 30_000
_MIN_DECODED_FRACTION = 0.9


class TruncatedVideoWarning(UserWarning):
    """Decoding ended before the end the container states: the file is probably cut short (a partial download or copy)."""


def _ebml_vint(b, i: int, strip: bool = True) -> tuple[int, int, bool]:
    first = b[i]
    n, mask = 1, 0x80
    while n <= 8 and not (first & mask):
        n, mask = n + 1, mask >> 1
    val = (first & (mask - 1)) if strip else first
    for k in range(1, min(n, len(b) - i)):
        val = (val << 8) | b[i + k]
    return val, n, val == (1 << (7 * n)) - 1


_MKV_DESCEND = (0x18538067, 0x1F43B675)  # Segment, Cluster: walk their children (their size may be unknown)
_MKV_SIMPLE_BLOCK = 0xA3


def matroska_ends_early(path: str | Path) -> tuple[bool, int] | None:
    """Whether a Matroska / WebM file ends inside an element (cut short), and how many frame blocks it holds.

    Walks the EBML structure (RFC 9559): elements of known size are skipped,
    the Segment and Clusters are entered (browser recorders write them with
    an unknown size, and state no duration and no frame count). A file whose
    last element runs past its end was cut short.

    Returns:
        ``(ends_early, n_simple_blocks)``, or ``None`` when the structure cannot be walked
        (not Matroska, or an element of unknown size other than Segment / Cluster).
    """
    import mmap

    with open(path, "rb") as fh:
        if Path(path).stat().st_size == 0:
            return None
        with mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as b:
            L, i, blocks = len(b), 0, 0
            if b[:4] != b"\x1a\x45\xdf\xa3":
                return None
            while i < L:
                eid, n1, _ = _ebml_vint(b, i, strip=False)
                if i + n1 >= L:
                    return True, blocks
                size, n2, unknown = _ebml_vint(b, i + n1)
                if eid in _MKV_DESCEND:
                    i += n1 + n2
                    continue
                if unknown:
                    return None
                if i + n1 + n2 + size > L:
                    return True, blocks
                blocks += eid == _MKV_SIMPLE_BLOCK
                i += n1 + n2 + size
            return False, blocks


def _fourcc(cap: cv2.VideoCapture) -> str | None:
    try:
        code = int(cap.get(cv2.CAP_PROP_FOURCC))
    except (TypeError, ValueError, OverflowError):
        return None
    if code <= 0:
        return None
    s = code.to_bytes(4, "little").decode("ascii", errors="replace")
    return s if s.isprintable() else None


def _warn_if_cut_short(path: Path, n: int, container_count: int | None, stated: int | None, container_fps: float) -> None:
    """Warn (:class:`TruncatedVideoWarning`) when ``n`` decoded frames fall short of what the container states.

    ``container_count`` is the trusted count (None if there is none), ``stated`` what OpenCV reported.
    A shortfall of at most 2 frames is not warned about (containers round their counts).
    """
    import warnings

    if container_count is not None and n < container_count - 2:
        warnings.warn(f"{path}: decoding ended early: {n} frames decoded of the {container_count} the container states", TruncatedVideoWarning, stacklevel=3)
        return
    if path.suffix.lower() in (".webm", ".mkv"):
        walked = matroska_ends_early(path)
        if walked is not None and walked[0]:
            says = "no frame count" if stated is None else f"{stated} frames, an estimate from its implausible {container_fps:g} fps"
            warnings.warn(
                f"{path}: the file is cut short (its last block runs past the end of the file): {n} frames decoded, "
                f"the container states {says}; the rest of the recording is missing",
                TruncatedVideoWarning,
                stacklevel=3,
            )


def read_video(
    path: str | Path,
    fps: float | None = None,
    max_fps: float = 240.0,
    jitter_tol: float = 0.05,
    *,
    start: int = 0,
    stop: int | None = None,
    transform: FrameTransform | None = None,
) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """Decode a video file into RGB frames and timestamps.

    Args:
        path: video file (anything FFmpeg reads: mp4, webm, mov, avi, mkv...).
        fps: true capture rate in Hz (``system.source.fps``) or None; see the
            timing rule in the module docstring.
        max_fps: a container fps above this (Hz) is absurd.
        jitter_tol: tolerated ``std(dt) / mean(dt)`` of the timestamps.
        start, stop: keep only frames ``[start, stop)`` (``stop=None``: to the
            end). Timing is still decided on all frames; the returned ``t``
            is the kept frames' times, shifted so that ``t[0] = 0``.
        transform: optional per-frame function applied to each kept frame
            (uint8 ``[H, W, 3]`` -> uint8 ``[h, w, 3]``), e.g. crop + resize,
            so that only small frames are held in memory.

    Returns:
        ``(frames, t, info)``: frames uint8 ``[T, h, w, 3]`` RGB; ``t`` float64
        ``[T]`` seconds, strictly increasing, ``t[0] = 0``; ``info`` a
        JSON-serialisable dict with ``container_fps``, ``rule`` (``"config_fps"
        | "timestamps" | "mean_rate"``, see :mod:`lagsplat.io.timing`),
        ``dt_ms_min`` / ``dt_ms_median`` / ``dt_ms_max`` (raw intervals),
        ``warnings`` (messages issued), ``container_frame_count`` (None if the
        container does not say), ``container_frame_count_trusted`` (False with
        an absurd container fps: then not used for the checks), ``n_decoded``, ``width`` / ``height`` (native
        pixels), ``codec`` and ``frames`` (the kept range).

    Raises:
        ClipError: ``"<path>: file not found"``; ``"<path>: cannot decode
            video (...)"`` if OpenCV cannot open it or decodes no frame;
            ``"<path>: video is truncated or corrupt: decoded N of M frames"`` (fewer
            than 90 % of a trusted container count);
            the timing rule's error; a frame range outside the video.

    Warns:
        TimingWarning: see the timing rule.
        TruncatedVideoWarning: decoding ended before what the container states
            (a frame count, or for WebM / Matroska a last block running past the end of the file).
    """
    path = Path(path)
    src = str(path)
    start, stop = validate_range(src, start, stop)
    if not path.exists():
        raise ClipError(f"{src}: file not found")
    if path.is_dir():
        raise ClipError(f"{src}: is a folder, not a video file")

    try:
        cap = cv2.VideoCapture(
            src, cv2.CAP_ANY, [cv2.CAP_PROP_OPEN_TIMEOUT_MSEC, _OPEN_TIMEOUT_MS, cv2.CAP_PROP_READ_TIMEOUT_MSEC, _OPEN_TIMEOUT_MS]
        )
    except cv2.error as exc:  # pragma: no cover - depends on the OpenCV build
        raise ClipError(f"{src}: cannot decode video (OpenCV error: {str(exc).strip().splitlines()[-1]})") from exc
    raw_ms: list[float] = []
    try:
        if not cap.isOpened():
            raise ClipError(
                f"{src}: cannot decode video (OpenCV/FFmpeg cannot open it: not a video, an unsupported codec, "
                f"or the file is truncated or corrupt)"
            )
        container_fps = float(cap.get(cv2.CAP_PROP_FPS))
        count = float(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        stated = int(count) if math.isfinite(count) and 0 < count < 2**31 else None
        # a count the container lacks is estimated by OpenCV as duration x fps: meaningless with an absurd fps
        container_count = stated if not is_absurd_fps(container_fps, max_fps) else None
        capacity = None
        if container_count is not None:
            capacity = max(0, min(container_count, stop if stop is not None else container_count) - start)
        collector = FrameCollector(src, start, stop, transform, capacity=capacity)
        width = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH))
        height = int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        codec = _fourcc(cap)
        backend = cap.getBackendName()
        native: tuple[int, int] | None = None
        i = 0
        while True:
            if not collector.wants(i):  # outside the range: demux + decode for the timestamp only
                if not cap.grab():
                    break
                raw_ms.append(float(cap.get(cv2.CAP_PROP_POS_MSEC)))
                i += 1
                continue
            ok, frame = cap.read()
            if not ok or frame is None:
                break
            raw_ms.append(float(cap.get(cv2.CAP_PROP_POS_MSEC)))
            rgb = cv_to_rgb(frame, src)
            hw = rgb.shape[:2]
            if native is None:
                native = hw
            elif hw != native:
                raise ClipError(f"{src}: frame {i} is {hw[1]}x{hw[0]} but earlier frames are {native[1]}x{native[0]}")
            collector.add(i, rgb)
            i += 1
    except cv2.error as exc:
        raise ClipError(f"{src}: cannot decode video (OpenCV error: {str(exc).strip().splitlines()[-1]})") from exc
    finally:
        cap.release()

    n = len(raw_ms)
    if n == 0:
        raise ClipError(f"{src}: cannot decode video (no frame could be decoded)")
    if container_count is not None and n < _MIN_DECODED_FRACTION * container_count:
        raise ClipError(f"{src}: video is truncated or corrupt: decoded {n} of {container_count} frames")
    _warn_if_cut_short(path, n, container_count, stated, container_fps)
    start, stop_ = check_range(src, start, stop, n)

    t_all, info = resolve_timing(
        np.asarray(raw_ms) / 1e3, src, fps=fps, container_fps=container_fps, max_fps=max_fps, jitter_tol=jitter_tol
    )
    t = t_all[start:stop_] - t_all[start]
    frames = collector.result()
    assert frames.shape[0] == t.shape[0]
    info.update(
        {
            "reader": "video",
            "backend": backend,
            "codec": codec,
            "container_frame_count": stated,
            "container_frame_count_trusted": container_count is not None,
            "n_decoded": n,
            "width": int(native[1]) if native else width,
            "height": int(native[0]) if native else height,
            "frames": [start, stop_],
            "t_start_s": float(t_all[start]),
        }
    )
    return frames, t, info
