"""The `Clip`: one recording, as every later stage reads it (artifact ``clip.npz``).

A clip holds frames, their real timestamps, the logged actuation and the
train / held-out split (DESIGN.md, "Data flows one way"). It is written once by
the ingest stage and never modified afterwards.

On-disk layout of ``clip.npz`` (all arrays, NumPy ``.npz``, uncompressed):

=============  ====================  ==========================================
key            dtype / shape         meaning
=============  ====================  ==========================================
``images``     uint8 ``[T,H,W,3]``   RGB frames
``t``          float64 ``[T]``       timestamps in seconds, strictly increasing
``u``          float32 ``[T,n_u]``   actuation channels (``n_u`` may be 0)
``u_names``    str ``[n_u]``         channel names, e.g. ``p1..p4``
``split``      int8 ``[T]``          0 = training frame, 1 = held-out frame
``episode``    int16 ``[T]``         recording each frame comes from (optional
                                     key, zeros if absent): several clips of
                                     one system are stored back to back and no
                                     window may cross an episode boundary
``meta``       str (JSON)            provenance, timing rule, known physics
=============  ====================  ==========================================
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lagsplat.io.atomic import atomic_write

__all__ = ["Clip", "ClipError", "save_clip", "load_clip", "segments", "concatenate_clips", "TRAIN", "HELD_OUT"]

TRAIN = 0
HELD_OUT = 1


def segments(split: np.ndarray, which: int, episode: np.ndarray | None = None) -> list[np.ndarray]:
    """Contiguous runs of frame indices whose ``split`` value equals ``which``.

    Args:
        split: int ``[T]`` split labels (``TRAIN`` / ``HELD_OUT``).
        which: the label to select.
        episode: optional int ``[T]`` recording index; a run also ends where
            the episode changes (multi-clip training).

    Returns:
        List of int64 index arrays, in time order (empty if none).
    """
    idx = np.flatnonzero(np.asarray(split) == which)
    if len(idx) == 0:
        return []
    cut = np.diff(idx) > 1
    if episode is not None:
        ep = np.asarray(episode)[idx]
        cut |= np.diff(ep) != 0
    return np.split(idx, np.flatnonzero(cut) + 1)


class ClipError(ValueError):
    """Raised when a clip (or the file it comes from) is unusable.

    The message always starts with the offending file path so a user sees, on
    one line, which file is wrong and why.
    """


@dataclass
class Clip:
    """A recorded (or synthetic) video with timestamps, actuation and split.

    Attributes:
        images: uint8 ``[T, H, W, 3]`` RGB frames.
        t: float64 ``[T]`` timestamps in seconds, strictly increasing.
        u: float32 ``[T, n_u]`` actuation (e.g. chamber pressures); ``n_u`` may be 0.
        u_names: names of the ``n_u`` actuation channels.
        split: int8 ``[T]``, ``TRAIN`` (0) or ``HELD_OUT`` (1) per frame.
        episode: int16 ``[T]``, the recording each frame comes from (several
            clips of one system concatenated; zeros for a single recording).
        meta: JSON-serialisable provenance and known physics (e.g. the
            synthetic generator's natural frequency under ``"truth"``).

    Raises:
        ClipError: from :meth:`validate` when shapes, dtypes or values are
            inconsistent.
    """

    images: np.ndarray
    t: np.ndarray
    u: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), np.float32))
    u_names: list[str] = field(default_factory=list)
    split: np.ndarray | None = None
    meta: dict[str, Any] = field(default_factory=dict)
    episode: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.t = np.asarray(self.t, dtype=np.float64)
        T = len(self.t)
        if self.u.size == 0:
            self.u = np.zeros((T, 0), np.float32)
        self.u = np.asarray(self.u, dtype=np.float32)
        if self.split is None:
            self.split = np.zeros(T, np.int8)
        self.split = np.asarray(self.split, dtype=np.int8)
        if self.episode is None:
            self.episode = np.zeros(T, np.int16)
        self.episode = np.asarray(self.episode, dtype=np.int16)
        self.u_names = [str(n) for n in self.u_names]

    # ------------------------------------------------------------------ views
    @property
    def n_frames(self) -> int:
        """Number of frames ``T``."""
        return int(self.images.shape[0])

    @property
    def dt(self) -> float:
        """Median frame interval in seconds."""
        return float(np.median(np.diff(self.t)))

    @property
    def train_idx(self) -> np.ndarray:
        """Indices of training frames, int64 ``[n_train]``."""
        return np.flatnonzero(self.split == TRAIN)

    @property
    def held_out_idx(self) -> np.ndarray:
        """Indices of held-out frames, int64 ``[n_held_out]``."""
        return np.flatnonzero(self.split == HELD_OUT)

    @property
    def no_held_out(self) -> str | None:
        """The note of a clip identified on all its frames, or ``None``.

        A clip too short for the held-out protocol (between about 2 and 6 periods of
        motion) arrives with every frame in training and ``meta["split"]["no_held_out"]``,
        a one-line string such as ``"no held-out validation (2.4 periods)"``; Stage 2 then
        trains on all frames and the evaluation and the diagnosis read it in-sample.
        ``None`` when the clip has held-out frames or carries no such note.
        """
        split_meta = self.meta.get("split") if isinstance(self.meta, dict) else None
        note = split_meta.get("no_held_out") if isinstance(split_meta, dict) else None
        if not isinstance(note, str) or not note or (self.split == HELD_OUT).any():
            return None
        return note

    def validate(self, source: str | Path = "<clip>") -> "Clip":
        """Check shapes, dtypes and values; return ``self``.

        Args:
            source: file name used in error messages.

        Raises:
            ClipError: naming ``source`` and the first problem found.
        """
        src = str(source)
        im = self.images
        if not isinstance(im, np.ndarray) or im.ndim != 4 or im.shape[-1] != 3:
            raise ClipError(f"{src}: images must be uint8 [T,H,W,3], got shape {getattr(im, 'shape', None)}")
        if im.dtype != np.uint8:
            raise ClipError(f"{src}: images must be uint8, got {im.dtype}")
        T = im.shape[0]
        if T < 2:
            raise ClipError(f"{src}: a clip needs at least 2 frames, got {T}")
        if self.t.shape != (T,):
            raise ClipError(f"{src}: timestamps t has shape {self.t.shape}, expected ({T},) to match {T} frames")
        if not np.all(np.isfinite(self.t)):
            raise ClipError(f"{src}: timestamps contain NaN or inf")
        if np.any(np.diff(self.t) <= 0):
            raise ClipError(f"{src}: timestamps are not strictly increasing")
        if self.u.ndim != 2 or self.u.shape[0] != T:
            raise ClipError(
                f"{src}: actuation has {self.u.shape[0] if self.u.ndim else 0} samples but the clip has {T} frames"
            )
        if self.u.shape[1] != len(self.u_names):
            raise ClipError(f"{src}: {self.u.shape[1]} actuation channels but {len(self.u_names)} names")
        bad = ~np.isfinite(self.u)
        if bad.any():
            ch = self.u_names[int(np.argwhere(bad)[0, 1])]
            raise ClipError(f"{src}: actuation channel '{ch}' contains NaN or inf ({int(bad.sum())} values)")
        if self.split.shape != (T,) or not np.isin(self.split, (TRAIN, HELD_OUT)).all():
            raise ClipError(f"{src}: split must be int8 [T] of 0 (train) / 1 (held-out)")
        if self.episode.shape != (T,) or (T and self.episode.min() < 0):
            raise ClipError(f"{src}: episode must be int16 [T] of non-negative recording indices")
        return self

    def segments(self, which: int) -> list[np.ndarray]:
        """Contiguous runs of frames with split ``which`` inside one episode."""
        return segments(self.split, which, self.episode)


def concatenate_clips(clips: list[Clip], held_out: list[bool], source: str = "<clips>") -> Clip:
    """Several recordings of one system as one clip of episodes (multi-clip training).

    Episode ``i`` is ``clips[i]``, every frame of it ``HELD_OUT`` if
    ``held_out[i]`` else ``TRAIN``. Times are shifted so that each episode
    starts one median frame interval after the previous one ends.

    Raises:
        ClipError: naming ``source`` if the recordings differ in frame size or
            actuation channels, or the lists differ in length.
    """
    if len(clips) != len(held_out) or not clips:
        raise ClipError(f"{source}: need one held_out flag per recording, got {len(clips)} clips and {len(held_out)} flags")
    first = clips[0]
    for i, c in enumerate(clips[1:], 1):
        if c.images.shape[1:] != first.images.shape[1:]:
            raise ClipError(f"{source}: recording {i} has frames {c.images.shape[1:3]}, recording 0 {first.images.shape[1:3]}")
        if c.u_names != first.u_names:
            raise ClipError(f"{source}: recording {i} has actuation {c.u_names}, recording 0 {first.u_names}")
    t, off = [], 0.0
    for c in clips:
        t.append(c.t - c.t[0] + off)
        off = t[-1][-1] + c.dt
    meta = {"episodes": [dict(c.meta, held_out=h, n_frames=c.n_frames) for c, h in zip(clips, held_out)]}
    meta.update({k: v for k, v in first.meta.items() if k in ("system", "crop", "resize", "size")})
    meta["split"] = {"kind": "episodes", "held_out": [i for i, h in enumerate(held_out) if h]}
    return Clip(
        images=np.concatenate([c.images for c in clips]),
        t=np.concatenate(t),
        u=np.concatenate([c.u for c in clips]),
        u_names=list(first.u_names),
        split=np.concatenate([np.full(c.n_frames, HELD_OUT if h else TRAIN, np.int8) for c, h in zip(clips, held_out)]),
        meta=meta,
        episode=np.concatenate([np.full(c.n_frames, i, np.int16) for i, c in enumerate(clips)]),
    ).validate(source)


def save_clip(path: str | Path, clip: Clip) -> Path:
    """Validate ``clip`` and write it atomically to ``path`` (``.npz``).

    Args:
        path: destination; its parent folder is created.
        clip: the clip to store.

    Returns:
        The path written.

    Raises:
        ClipError: if the clip does not validate; nothing is written then.
    """
    path = Path(path)
    clip.validate(path)
    with atomic_write(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez(
                fh,
                images=clip.images,
                t=clip.t,
                u=clip.u,
                u_names=np.array(clip.u_names, dtype=str),
                split=clip.split,
                episode=clip.episode,
                meta=np.array(json.dumps(clip.meta, sort_keys=True)),
            )
    return path


def load_clip(path: str | Path) -> Clip:
    """Read a ``clip.npz`` written by :func:`save_clip`.

    Raises:
        ClipError: if the file is missing, unreadable or lacks a key.
    """
    path = Path(path)
    if not path.exists():
        raise ClipError(f"{path}: file not found")
    try:
        with np.load(path, allow_pickle=False) as z:
            missing = [k for k in ("images", "t", "u", "u_names", "split", "meta") if k not in z.files]
            if missing:
                raise ClipError(f"{path}: not a lagsplat clip, missing keys {missing}")
            clip = Clip(
                images=z["images"],
                t=z["t"],
                u=z["u"],
                u_names=list(z["u_names"]),
                split=z["split"],
                meta=json.loads(str(z["meta"])),
                episode=z["episode"] if "episode" in z.files else None,
            )
    except ClipError:
        raise
    except Exception as exc:  # zipfile.BadZipFile, ValueError, EOFError, ...
        raise ClipError(f"{path}: cannot read clip ({type(exc).__name__}: {exc})") from exc
    return clip.validate(path)
