"""Fetch a file by URL and check its SHA256, atomically, through pooch.

``fetch(url, dest, sha256)`` hands the work to :func:`pooch.retrieve`
(https://www.fatiando.org/pooch/) with ``known_hash="sha256:..."``: it returns
at once if ``dest`` already holds the right bytes; otherwise pooch streams the
URL into a temporary file beside ``dest``, checks the SHA256 and only then
moves it onto ``dest``; on any failure the temporary file is removed and
``dest`` is left as it was. What this module adds to pooch: ``file://`` URLs
(a local copy, e.g. in tests), quiet logging, and one-line
:class:`DownloadError` messages that say what to do, e.g. when offline::

    cannot download https://... (Connection refused); you appear to be offline:
    download it by hand and place it at data/raw/x.webm (sha256 061e...)

Command line (for Snakemake rules)::

    python -m lagsplat.io.download URL DEST SHA256

prints the destination on success; on failure it prints the one-line error
to stderr and exits with status 1 (no traceback).
"""

from __future__ import annotations

import contextlib
import logging
import re
import shutil
import sys
from pathlib import Path
from urllib.parse import urlsplit
from urllib.request import url2pathname

import pooch

__all__ = ["DownloadError", "fetch", "sha256_file", "main"]

_CHUNK = 1 << 20  # bytes per read of a download
_USER_AGENT = "lagsplat-fetch/0.1 (pooch)"


class DownloadError(RuntimeError):
    """A file could not be fetched or did not match its SHA256 (one-line message)."""


def sha256_file(path: str | Path) -> str:
    """Return the lower-case hex SHA256 of a file's bytes (:func:`pooch.file_hash`, read in chunks).

    Raises:
        OSError: if the file cannot be read.
    """
    return pooch.file_hash(str(path), alg="sha256")


def check_digest(sha256: str) -> str:
    """``sha256`` stripped and lower-cased; raises ``ValueError`` unless it is 64 hex digits."""
    expected = str(sha256).strip().lower()
    if len(expected) != 64 or any(c not in "0123456789abcdef" for c in expected):
        raise ValueError(f"sha256 must be 64 hex digits, got {sha256!r}")
    return expected


def failure_reason(exc: BaseException) -> str:
    """A short human reason for a failed download: an HTTP status, the network or OS error at the root."""
    response = getattr(exc, "response", None)
    if response is not None and getattr(response, "status_code", None):
        return f"HTTP {response.status_code} {response.reason}"
    if isinstance(exc, TimeoutError) or type(exc).__name__ in ("ReadTimeout", "ConnectTimeout", "Timeout"):
        return "timed out"
    if isinstance(exc, OSError) and exc.strerror:
        return exc.strerror
    for inner in (getattr(exc, "reason", None), exc.args[0] if exc.args else None, exc.__cause__):
        if isinstance(inner, BaseException) and inner is not exc:
            return failure_reason(inner)
    return str(exc) or type(exc).__name__


@contextlib.contextmanager
def quiet_pooch():
    """Silence pooch's INFO lines ("Downloading data from ...") so a failure prints one line only."""
    log = pooch.get_logger()
    level = log.level
    log.setLevel(logging.WARNING)
    try:
        yield
    finally:
        log.setLevel(level)


def _downloader(url: str, by_hand: str, timeout: float, progress: bool):
    """The pooch downloader for ``url``: pooch's HTTP one, a copy for ``file://``, or one that refuses the scheme.

    pooch calls it only when a download is needed, into its temporary file (which it then verifies and moves).
    """
    scheme = url.split(":", 1)[0].lower() if ":" in url else ""
    if scheme in ("http", "https"):
        return pooch.HTTPDownloader(progressbar=progress, chunk_size=_CHUNK, timeout=timeout, headers={"User-Agent": _USER_AGENT})

    def local_or_refuse(url: str, output_file: str, _pooch: object) -> None:
        if scheme != "file":
            raise DownloadError(f"cannot download {url} (unsupported URL scheme {scheme!r}; use http, https or file); {by_hand}")
        try:
            src = open(url2pathname(urlsplit(url).path), "rb")
        except OSError as exc:
            raise DownloadError(f"cannot download {url} ({failure_reason(exc)}); {by_hand}") from None
        with src, open(output_file, "wb") as out:
            shutil.copyfileobj(src, out, _CHUNK)

    return local_or_refuse


def retrieve(url: str, dest: Path, known_hash: str | None, by_hand: str, timeout: float = 60, progress: bool = False) -> Path:
    """:func:`pooch.retrieve` ``url`` to ``dest`` with ``known_hash`` (``"sha256:<hex>"`` or ``None``).

    Args:
        url: ``http(s)://`` or ``file://`` URL.
        dest: destination path; its folder is created if needed. A file there
            whose hash matches ``known_hash`` is returned without a download
            (with ``known_hash=None``, any file there is).
        known_hash: pooch's hash string, or ``None`` to skip the check.
        by_hand: advice ending the error messages ("download it by hand ...").
        timeout: seconds allowed for connecting and for each read.
        progress: pooch's tqdm progress bar (bytes) on stderr while downloading
            over HTTP, drawn once the server has answered (a refused request
            prints nothing); ``TQDM_MININTERVAL=30`` thins it in a log file.

    Returns:
        ``dest``.

    Raises:
        DownloadError: one line: ``"sha256 mismatch for <url>: expected X, got Y"``,
            ``"cannot download <url> (<reason>); <by_hand>"`` (an HTTP status,
            a missing local file, an unsupported scheme), the same with ``"you
            appear to be offline: "`` before ``by_hand`` for a network failure,
            or ``"cannot write the download of <url> to <folder> (<reason>)"``.
    """
    import requests

    try:
        with quiet_pooch():
            pooch.retrieve(url, known_hash, fname=dest.name, path=dest.parent, downloader=_downloader(url, by_hand, timeout, progress))
    except requests.exceptions.RequestException as exc:  # an HTTP status or a malformed URL (a ValueError) is no network failure
        offline = "" if isinstance(exc, (requests.exceptions.HTTPError, ValueError)) else "you appear to be offline: "
        raise DownloadError(f"cannot download {url} ({failure_reason(exc)}); {offline}{by_hand}") from None
    except ValueError as exc:  # pooch's hash mismatch ("... expected sha256:X but got Y. ...")
        if known_hash is None or "does not match the known hash" not in str(exc):
            raise DownloadError(f"cannot download {url} ({exc}); {by_hand}") from None
        got = re.search(r"but got ([0-9a-fA-F]+)", str(exc))
        raise DownloadError(f"sha256 mismatch for {url}: expected {known_hash.split(':')[-1]}, "
                            f"got {got.group(1).lower() if got else 'a different digest'}") from None
    except OSError as exc:  # a local write: disk full, read-only folder (network errors come as requests' exceptions)
        raise DownloadError(f"cannot write the download of {url} to {dest.parent} ({failure_reason(exc)})") from None
    return dest


def fetch(url: str, dest: str | Path, sha256: str, timeout: float = 60) -> Path:
    """Make ``dest`` hold the file at ``url`` whose SHA256 is ``sha256`` (through :func:`pooch.retrieve`).

    Args:
        url: ``http://``, ``https://`` or ``file://`` URL.
        dest: destination path; its folder is created if needed.
        sha256: expected hex digest (64 hex digits, any case).
        timeout: seconds allowed for connecting and for each read.

    Returns:
        ``dest`` as a :class:`~pathlib.Path`; nothing is downloaded when it
        already holds the right bytes.

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
    expected = check_digest(sha256)
    by_hand = f"download it by hand and place it at {dest} (sha256 {expected})"
    return retrieve(url, dest, f"sha256:{expected}", by_hand, timeout=timeout)


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
