"""The bottom layer: read videos, image folders, .npz and .mcap recordings; the clip artifact; atomic writes.

Public entry points (a system configuration becomes a clip in :mod:`lagsplat.ingest`, one layer up):

* Readers: :func:`read_video`, :func:`read_image_folder`, :func:`read_npz`,
  :func:`read_mcap` (all raise :class:`ClipError` with one line naming the file).
* Timing rule: :func:`resolve_timing`, :class:`TimingWarning`.
* Downloads (through pooch): :func:`fetch`, :func:`sha256_file`, :class:`DownloadError`
  (command line: ``python -m lagsplat.io.download URL DEST SHA256``); a member of a
  zip archive: :mod:`lagsplat.io.zenodo`.
* The clip artifact: :class:`Clip`, :func:`save_clip`, :func:`load_clip`.

Names are imported lazily on first use, so ``import lagsplat.io.clip`` does not
load OpenCV or mcap, and ``python -m lagsplat.io.download`` runs cleanly.
"""

from __future__ import annotations

from lagsplat.lazy import lazy_exports

_EXPORTS = {
    "atomic_write": "atomic",
    "save_torch": "atomic",
    "write_json": "atomic",
    "write_npz": "atomic",
    "Clip": "clip",
    "ClipError": "clip",
    "HELD_OUT": "clip",
    "TRAIN": "clip",
    "load_clip": "clip",
    "save_clip": "clip",
    "DownloadError": "download",
    "fetch": "download",
    "sha256_file": "download",
    "IMAGE_EXTENSIONS": "images",
    "read_image_folder": "images",
    "read_mcap": "mcap_io",
    "zero_order_hold": "mcap_io",
    "read_npz": "npz",
    "TimingWarning": "timing",
    "resolve_timing": "timing",
    "VIDEO_EXTENSIONS": "video",
    "read_video": "video",
}

__all__ = sorted(_EXPORTS)


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
