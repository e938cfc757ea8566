"""Fetch a file by URL and check its SHA256, atomically.

``fetch(url, dest, sha256)`` returns at once if ``dest`` already holds the
right bytes. Otherwise it downloads (``urllib``: ``http(s)://``, ``file://``)
into a hidden temporary file beside ``dest``, checks the SHA256 and only then
renames it onto ``dest``; on any failure the temporary file is removed and
``dest`` is not created. Failures raise :class:`DownloadError` with one line
that says what to do, e.g. when offline::

    cannot download https://... (Connection refused); you appear to be offline:
    download it by hand and place it at data/raw/x.webm (sha256 061e...)

Command line (for Snakemake rules)::

    python -m lagsplat.io.download URL DEST SHA256

prints the destination on success; on failure it prints the one-line error
to stderr and exits with status 1 (no traceback).
"""

from __future__ import annotations

import contextlib
import hashlib
import http.client
import os
import socket
import sys
import tempfile
import urllib.error
import urllib.parse
import urllib.request
from pathlib import Path

__all__ = ["DownloadError", "fetch", "sha256_file", "main"]

_CHUNK = 1 << 20
_USER_AGENT = "lagsplat-fetch/0.1"


class DownloadError(RuntimeError):
    """A file could not be fetched or did not match its SHA256 (one-line message)."""


def sha256_file(path: str | Path) -> str:
    """Return the lower-case hex SHA256 of a file's bytes (read in 1 MiB chunks).

    Raises:
        OSError: if the file cannot be read.
    """
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(_CHUNK), b""):
            h.update(chunk)
    return h.hexdigest()


def failure_reason(exc: BaseException) -> str:
    """A short human reason for a failed download (HTTP status, network error, OS error)."""
    if isinstance(exc, urllib.error.HTTPError):
        return f"HTTP {exc.code} {exc.reason}"
    if isinstance(exc, urllib.error.URLError):
        r = exc.reason
        if isinstance(r, BaseException):
            return failure_reason(r)
        return str(r)
    if isinstance(exc, (socket.timeout, TimeoutError)):
        return "timed out"
    if isinstance(exc, OSError) and exc.strerror:
        return exc.strerror
    return str(exc) or type(exc).__name__


def fetch(url: str, dest: str | Path, sha256: str, timeout: float = 60) -> Path:
    """Make ``dest`` hold the file at ``url`` whose SHA256 is ``sha256``.

    Args:
        url: ``http://``, ``https://`` or ``file://`` URL.
        dest: destination path; its folder is created if needed.
        sha256: expected hex digest (64 hex digits, any case).
        timeout: seconds allowed for connecting and for each read.

    Returns:
        ``dest`` as a :class:`~pathlib.Path`.

    Raises:
        DownloadError: one line, either ``"sha256 mismatch for <url>:
            expected X, got Y"`` (nothing is left at ``dest``, unless a file
            was there before, which is never touched), or ``"cannot download
            <url> (<reason>); you appear to be offline: download it by hand
            and place it at <dest> (sha256 <X>)"`` for a network failure
            (an HTTP error status or a bad URL say so instead of "offline").
        ValueError: if ``sha256`` is not 64 hex digits.
    """
    dest = Path(dest)
    expected = str(sha256).strip().lower()
    if len(expected) != 64 or any(c not in "0123456789abcdef" for c in expected):
        raise ValueError(f"sha256 must be 64 hex digits, got {sha256!r}")
    if dest.is_file() and sha256_file(dest) == expected:
        return dest

    by_hand = f"download it by hand and place it at {dest} (sha256 {expected})"
    scheme = urllib.parse.urlsplit(url).scheme.lower()
    dest.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{dest.name}.", suffix=".part", dir=dest.parent)
    tmp = Path(tmp_name)
    try:
        h = hashlib.sha256()
        with os.fdopen(fd, "wb") as out:
            try:
                req = urllib.request.Request(url, headers={"User-Agent": _USER_AGENT})
                with urllib.request.urlopen(req, timeout=timeout) as resp:
                    for chunk in iter(lambda: resp.read(_CHUNK), b""):
                        h.update(chunk)
                        out.write(chunk)
            except urllib.error.HTTPError as exc:
                raise DownloadError(f"cannot download {url} ({failure_reason(exc)}); {by_hand}") from None
            except ValueError as exc:  # unknown url type, malformed URL
                raise DownloadError(f"cannot download {url} ({exc}); {by_hand}") from None
            except (urllib.error.URLError, OSError, http.client.HTTPException) as exc:
                if scheme == "file" and not isinstance(exc, (socket.timeout, TimeoutError)):
                    raise DownloadError(f"cannot download {url} ({failure_reason(exc)}); {by_hand}") from None
                raise DownloadError(
                    f"cannot download {url} ({failure_reason(exc)}); you appear to be offline: {by_hand}"
                ) from None
        got = h.hexdigest()
        if got != expected:
            raise DownloadError(f"sha256 mismatch for {url}: expected {expected}, got {got}")
        os.replace(tmp, dest)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        raise
    return dest


def main(argv: list[str] | None = None) -> int:
    """CLI: ``python -m lagsplat.io.download URL DEST SHA256``; returns the exit status."""
    args = sys.argv[1:] if argv is None else list(argv)
    if len(args) != 3 or any(a in ("-h", "--help") for a in args):
        print("usage: python -m lagsplat.io.download URL DEST SHA256", file=sys.stderr)
        return 2
    url, dest, sha = args
    try:
        path = fetch(url, dest, sha)
    except (DownloadError, ValueError, OSError) as exc:
        msg = " ".join(str(exc).split())
        print(f"error: {msg}", file=sys.stderr)
        return 1
    print(path)
    return 0


if __name__ == "__main__":  # pragma: no cover - exercised through a subprocess in tests
    sys.exit(main())
