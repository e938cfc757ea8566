"""Atomic file writes: an artifact exists complete or not at all."""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from pathlib import Path
from typing import Any, Iterator

__all__ = ["atomic_write", "write_json", "write_npz", "save_torch"]


@contextlib.contextmanager
def atomic_write(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` on success.

    If the body raises, the temporary file is removed and ``path`` is left
    untouched, so no partial artifact ever looks complete.

    Args:
        path: final destination. Its parent folder is created if needed.

    Yields:
        A temporary file path in the same folder (same file system, so the
        final ``os.replace`` is atomic). The final file's mode follows the
        user's umask (``0o666 & ~umask``), like a file opened for writing.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        if tmp_path.exists():  # mkstemp made it 0600; the artifact gets the user's umask, as open() would give it
            os.chmod(tmp_path, 0o666 & ~_umask())
        os.replace(tmp_path, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()
        raise


def _umask() -> int:
    """The process's file-creation mask (read by setting it and putting it back)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def write_json(path: str | Path, obj: Any) -> Path:
    """Write ``obj`` as indented JSON, atomically. Returns the path."""
    with atomic_write(path) as tmp:
        tmp.write_text(json.dumps(obj, indent=2, sort_keys=False) + "\n")
    return Path(path)


def write_npz(path: str | Path, compressed: bool = True, **arrays: Any) -> Path:
    """Write ``arrays`` as an ``.npz`` (``np.savez_compressed``, or ``np.savez``), atomically. Returns the path."""
    import numpy as np

    with atomic_write(path) as tmp:
        with open(tmp, "wb") as fh:  # a file object: numpy must not append ".npz" to the temporary name
            (np.savez_compressed if compressed else np.savez)(fh, **arrays)
    return Path(path)


def save_torch(path: str | Path, obj: Any) -> Path:
    """``torch.save`` ``obj`` atomically. Returns the path."""
    import torch

    with atomic_write(path) as tmp:
        torch.save(obj, tmp)
    return Path(path)
