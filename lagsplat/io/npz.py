"""Read a NumPy ``.npz`` recording (the Krauss soft-robot layout and friends).

Keys:

* ``images`` (required), any of
    - ``(T, H, W, 3)`` uint8 or float,
    - ``(T, 3, H, W)`` float in [0, 1] (the Krauss layout, channel first),
    - ``(T, H, W)`` gray (replicated to RGB); a single channel
      ``(T, H, W, 1)`` / ``(T, 1, H, W)`` is gray too, and a 4th (alpha)
      channel is dropped.

  The channel axis is the last one when it has 3 entries and the second
  axis does not; the second one when it has 3 entries (so an ambiguous
  ``(T, 3, H, 3)`` counts as channel first, as in the Krauss loader);
  otherwise whichever of the two has 1 or 4 entries (both: error). Float
  images must lie in [0, 1] (tolerance 1e-3) and become ``round(255 x)``;
  integer images must lie in [0, 255].
* ``t`` (optional): float ``[T]`` timestamps in seconds. Otherwise ``fps`` or
  ``dt`` must be given and ``t_i = i / fps`` (or ``i * dt``). If ``t`` is
  present it wins, and a stated ``fps`` / ``dt`` that disagrees with its mean
  rate by more than 1 % is warned about.
* Actuation: the keys named in ``actuation_keys``; if that is None, every
  key whose name starts with ``p`` and holds a 1-D numeric array, in natural
  order (``p1, p2, ..., p10``): the Krauss convention, where ``p1..p4`` are
  chamber pressures already divided by 101 325 Pa. A selected 1-D ``p*`` key
  whose length differs from ``T`` is an error, not silently dropped (it is
  most likely a misaligned log); ``p*`` keys that are not 1-D numeric arrays
  are ignored (listed in ``info["ignored_keys"]``).
"""

from __future__ import annotations

import math
import warnings
import zipfile
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from lagsplat.io.common import FrameCollector, FrameTransform, check_range, natural_key, validate_range
from lagsplat.io.clip import ClipError
from lagsplat.io.timing import TimingWarning

__all__ = ["read_npz", "images_to_uint8_rgb"]

_FLOAT_TOL = 1e-3
_CHUNK = 512


def _channel_last(src: str, im: np.ndarray) -> np.ndarray:
    """Return a ``[T, H, W, C]`` view of ``im`` (C in 1, 3, 4)."""
    if im.ndim == 3:
        return im[..., None]
    if im.ndim != 4:
        raise ClipError(f"{src}: 'images' must have shape (T,H,W,3), (T,3,H,W) or (T,H,W), got {im.shape}")
    last, second = im.shape[-1], im.shape[1]
    if last == 3 and second != 3:
        return im
    if second == 3:  # also (T, 3, H, 3): channel first, as the Krauss loader reads it
        return np.moveaxis(im, 1, -1)
    if last in (1, 4) and second not in (1, 4):
        return im
    if second in (1, 4) and last not in (1, 4):
        return np.moveaxis(im, 1, -1)
    raise ClipError(f"{src}: 'images' has shape {im.shape}: cannot tell which axis holds the colour channels")


def images_to_uint8_rgb(images: np.ndarray, source: str | Path = "<images>") -> np.ndarray:
    """Convert an image array in any layout of the module docstring to uint8 RGB.

    Args:
        images: ``(T,H,W,C)``, ``(T,C,H,W)`` or ``(T,H,W)``; uint8, other
            integers in [0, 255], bool is refused, float in [0, 1].
        source: name used in error messages.

    Returns:
        uint8 ``[T, H, W, 3]``.

    Raises:
        ClipError: for an unknown layout, a non-numeric dtype, non-finite
            values, or values outside the allowed range.
    """
    src = str(source)
    im = _channel_last(src, np.asarray(images))
    if im.dtype == np.bool_ or not (np.issubdtype(im.dtype, np.integer) or np.issubdtype(im.dtype, np.floating)):
        raise ClipError(f"{src}: 'images' has unsupported dtype {im.dtype}")
    T, H, W, C = im.shape
    out = np.empty((T, H, W, 3), np.uint8)
    for a in range(0, T, _CHUNK):
        x = im[a:a + _CHUNK]
        if C == 4:
            x = x[..., :3]
        if np.issubdtype(x.dtype, np.floating):
            if not np.all(np.isfinite(x)):
                raise ClipError(f"{src}: 'images' contains NaN or inf")
            lo, hi = float(x.min()), float(x.max())
            if lo < -_FLOAT_TOL or hi > 1 + _FLOAT_TOL:
                raise ClipError(
                    f"{src}: float 'images' must lie in [0, 1], found values in [{lo:.4g}, {hi:.4g}]"
                    + (" (looks like 0..255: store uint8 or divide by 255)" if hi > 2 else "")
                )
            x = np.rint(np.clip(x, 0.0, 1.0) * 255.0).astype(np.uint8)
        elif x.dtype != np.uint8:
            lo, hi = int(x.min()), int(x.max())
            if lo < 0 or hi > 255:
                raise ClipError(f"{src}: integer 'images' must lie in [0, 255], found values in [{lo}, {hi}]")
            x = x.astype(np.uint8)
        out[a:a + _CHUNK] = x if x.shape[-1] == 3 else np.repeat(x, 3, axis=-1)
    return out


def _rate_from(src: str, fps: float | None, dt: float | None) -> float | None:
    def pos(name: str, v: Any) -> float:
        try:
            f = float(v)
        except (TypeError, ValueError):
            f = float("nan")
        if not math.isfinite(f) or f <= 0:
            raise ClipError(f"{src}: {name} must be a positive number, got {v!r}")
        return f

    rate = pos("system.source.fps", fps) if fps is not None else None
    if dt is not None:
        r2 = 1.0 / pos("system.source.dt", dt)
        if rate is not None and abs(rate * float(dt) - 1.0) > 1e-6:
            raise ClipError(f"{src}: system.source.fps={fps} and system.source.dt={dt} disagree")
        rate = r2 if rate is None else rate
    return rate


def read_npz(
    path: str | Path,
    fps: float | None = None,
    dt: float | None = None,
    actuation_keys: Sequence[str] | None = None,
    *,
    start: int = 0,
    stop: int | None = None,
    transform: FrameTransform | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str], dict[str, Any]]:
    """Read frames, timestamps and actuation from an ``.npz`` file.

    Args:
        path: the ``.npz`` file.
        fps: capture rate in Hz, used when the file has no ``t`` key.
        dt: frame interval in seconds, alternative to ``fps``.
        actuation_keys: names of the 1-D actuation keys; None selects every
            1-D numeric key starting with ``p`` (Krauss convention, see module
            docstring); ``[]`` selects none.
        start, stop: keep only frames ``[start, stop)``.
        transform: optional per-frame function (uint8 ``[H, W, 3]`` -> uint8
            ``[h, w, 3]``) applied after conversion to uint8 RGB.

    Returns:
        ``(frames, t, u, u_names, info)``: frames uint8 ``[T, h, w, 3]`` RGB;
        ``t`` float64 ``[T]`` seconds with ``t[0] = 0``; ``u`` float32
        ``[T, n_u]``; ``u_names`` the ``n_u`` key names; ``info`` with
        ``rule`` (``"file_t" | "config_fps"``), ``fps``, ``layout`` (shape
        and dtype of ``images``), native ``width`` / ``height``, ``keys``,
        ``ignored_keys``, ``frames``, ``warnings``.

    Raises:
        ClipError: missing or unreadable / truncated file; no ``images`` key
            (``"<path>: no 'images' array (keys found: ...)"``); bad image
            layout or values; no timing (no ``t`` and neither ``fps`` nor
            ``dt``); ``t`` not ``[T]`` strictly increasing finite; an
            actuation key missing, not 1-D numeric, of the wrong length
            (``"<path>: actuation 'p3' has 1000 samples but 'images' has 1200
            frames"``) or holding NaN / inf.

    Warns:
        TimingWarning: if ``t`` exists and a stated ``fps`` / ``dt`` disagrees
            with it by more than 1 %.
    """
    path = Path(path)
    src = str(path)
    start, stop = validate_range(src, start, stop)
    if not path.exists():
        raise ClipError(f"{src}: file not found")
    if path.is_dir():
        raise ClipError(f"{src}: is a folder, not an .npz file")
    rate = _rate_from(src, fps, dt)
    try:
        with np.load(path, allow_pickle=False) as z:
            if not isinstance(z, np.lib.npyio.NpzFile):
                raise ClipError(f"{src}: not an .npz archive (a single .npy array)")
            keys = list(z.files)
            if "images" not in keys:
                raise ClipError(f"{src}: no 'images' array (keys found: {', '.join(keys) or 'none'})")
            raw = z["images"]
            t_raw = z["t"] if "t" in keys else None
            if actuation_keys is None:
                chosen, ignored = [], []
                for k in sorted((k for k in keys if k.startswith("p")), key=natural_key):
                    a = z[k]
                    if a.ndim == 1 and (np.issubdtype(a.dtype, np.number) and not np.issubdtype(a.dtype, np.complexfloating)):
                        chosen.append((k, a))
                    else:
                        ignored.append(k)
            else:
                ignored = []
                chosen = []
                for k in actuation_keys:
                    k = str(k)
                    if k not in keys:
                        raise ClipError(f"{src}: no actuation key '{k}' (keys found: {', '.join(keys)})")
                    chosen.append((k, z[k]))
    except ClipError:
        raise
    except (zipfile.BadZipFile, ValueError, OSError, EOFError, KeyError) as exc:
        raise ClipError(f"{src}: cannot read .npz, the file is truncated or corrupt ({type(exc).__name__}: {exc})") from exc

    layout = {"shape": list(raw.shape), "dtype": str(raw.dtype)}
    if raw.ndim not in (3, 4):
        raise ClipError(f"{src}: 'images' must have shape (T,H,W,3), (T,3,H,W) or (T,H,W), got {raw.shape}")
    T = int(raw.shape[0])
    if T == 0:
        raise ClipError(f"{src}: 'images' holds no frames")

    # timing
    warn_msgs: list[str] = []
    if t_raw is not None:
        t_all = np.asarray(t_raw)
        if t_all.shape != (T,) or not np.issubdtype(t_all.dtype, np.number):
            raise ClipError(f"{src}: 't' must be a numeric [T] array of seconds, got {t_all.dtype} {t_all.shape} for {T} frames")
        t_all = t_all.astype(np.float64)
        if not np.all(np.isfinite(t_all)):
            raise ClipError(f"{src}: 't' contains NaN or inf")
        if T > 1 and np.any(np.diff(t_all) <= 0):
            raise ClipError(f"{src}: 't' is not strictly increasing")
        rule = "file_t"
        span = float(t_all[-1] - t_all[0])
        eff_fps = (T - 1) / span if T > 1 else None
        if rate is not None and eff_fps is not None and abs(eff_fps / rate - 1) > 0.01:
            msg = f"{src}: key 't' runs at {eff_fps:.4g} fps on average but the configuration states {rate:g} fps; using 't'"
            warn_msgs.append(msg)
            warnings.warn(msg, TimingWarning, stacklevel=2)
    elif rate is not None:
        t_all = np.arange(T, dtype=np.float64) / rate
        rule = "config_fps"
        eff_fps = rate
    else:
        raise ClipError(f"{src}: no 't' key and no frame rate; set system.source.fps (or system.source.dt)")

    # actuation
    names: list[str] = []
    cols: list[np.ndarray] = []
    for k, a in chosen:
        a = np.asarray(a)
        if a.ndim != 1:
            raise ClipError(f"{src}: actuation '{k}' must be 1-D with one sample per frame, got shape {a.shape}")
        if not np.issubdtype(a.dtype, np.number) or np.issubdtype(a.dtype, np.complexfloating):
            raise ClipError(f"{src}: actuation '{k}' must be real numbers, got {a.dtype}")
        if a.shape[0] != T:
            raise ClipError(f"{src}: actuation '{k}' has {a.shape[0]} samples but 'images' has {T} frames")
        a32 = a.astype(np.float32)
        bad = ~np.isfinite(a32)
        if bad.any():
            raise ClipError(f"{src}: actuation '{k}' contains NaN or inf ({int(bad.sum())} of {T} samples)")
        names.append(k)
        cols.append(a32)

    start, stop_ = check_range(src, start, stop, T)
    sel = raw[start:stop_]
    collector = FrameCollector(src, 0, None, transform)
    for a in range(0, sel.shape[0], _CHUNK):
        for j, fr in enumerate(images_to_uint8_rgb(sel[a:a + _CHUNK], src)):
            collector.add(a + j, fr)
    frames = collector.result()
    native = collector.native_shape
    assert native is not None
    t = t_all[start:stop_] - t_all[start]
    u = np.stack(cols, axis=1)[start:stop_] if cols else np.zeros((stop_ - start, 0), np.float32)
    info = {
        "reader": "npz",
        "rule": rule,
        "fps": eff_fps,
        "container_fps": None,
        "layout": layout,
        "width": native[1],
        "height": native[0],
        "keys": keys,
        "ignored_keys": ignored,
        "n_frames_in_file": T,
        "frames": [start, stop_],
        "t_start_s": float(t_all[start]),
        "warnings": warn_msgs,
    }
    return frames, t, np.ascontiguousarray(u, dtype=np.float32), names, info
