"""Fetch a zip archive, extract one member, verify the member's SHA256, atomically (through pooch).

Data published as one large archive (e.g. Zenodo record 17812071,
``processed_data.zip``, about 4.5 GB, holding the soft-robot recordings of
Krauss et al. 2026) come with a checksum for the files inside, not for the
archive. So the member is what is verified:

* :func:`fetch_archive` downloads the archive (``http(s)://`` or ``file://``;
  :func:`pooch.retrieve` with ``known_hash=None``, through
  :func:`lagsplat.io.download.retrieve`) to a hidden temporary name beside its
  destination, checks that it is a readable zip listing the expected members,
  and only then renames it into place. It has no checksum to verify: the
  archive is trusted only as far as the members extracted from it match theirs.
* :func:`extract_member` unpacks one member of a local archive with
  ``pooch.Unzip(members=[member])`` into a hidden temporary folder beside its
  destination (zipfile checks the member's CRC-32 on the way), compares its
  SHA256 (:func:`pooch.file_hash`) and renames it into place.
* :func:`fetch_member` composes the two: it returns at once if the
  destination already holds the right bytes; otherwise it uses a local archive
  the user gave (``archive=``, never modified or deleted), an archive cached
  by an earlier download (``cache=``), or downloads one. An archive downloaded
  by the call is deleted if extraction fails (wrong archive, missing member,
  checksum mismatch), and so is one downloaded without a ``cache`` path once
  the member is out.

Every failure raises :class:`~lagsplat.io.download.DownloadError` with one
line saying what is wrong and what to do; nothing partial is left behind
(no temporary file, no destination file). When offline::

    cannot download https://zenodo.org/... (Connection refused); you appear to be
    offline: download https://zenodo.org/... by hand and place it at
    data/raw/processed_data.zip, or place its member processed_data/x.npz at
    data/raw/x.npz (sha256 dd2d...)

Command line (for Snakemake rules)::

    python -m lagsplat.io.zenodo archive URL DEST [--member NAME ...] [--hint TEXT]
    python -m lagsplat.io.zenodo member ARCHIVE_OR_URL MEMBER DEST SHA256 [--cache PATH]

``archive`` downloads an archive and checks it lists each ``--member``;
``member`` extracts (from a local archive path, or from a URL through
:func:`fetch_member`). Both print the destination on success; on failure they
print the one-line error to stderr and exit with status 1 (no traceback).
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import zipfile
import zlib
from collections.abc import Iterable
from pathlib import Path

import pooch

from lagsplat.io.download import (
    DownloadError,
    check_digest,
    failure_reason,
    quiet_pooch,
    retrieve,
    sha256_file,
)

__all__ = ["fetch_archive", "extract_member", "fetch_member", "main"]


def _tmp_name(dest: Path, suffix: str = ".part") -> Path:
    """A unique unused hidden path beside ``dest`` (its folder is created)."""
    dest.parent.mkdir(parents=True, exist_ok=True)
    fd, name = tempfile.mkstemp(prefix=f".{dest.name}.", suffix=suffix, dir=dest.parent)
    os.close(fd)
    os.unlink(name)  # only the name is reserved: pooch would take an existing file for a cached download
    return Path(name)


def _members(archive: Path, label: str) -> set[str]:
    """Names listed in the zip's central directory; one-line error if it is not a readable zip."""
    try:
        with zipfile.ZipFile(archive) as zf:
            return set(zf.namelist())
    except (zipfile.BadZipFile, zipfile.LargeZipFile, OSError, EOFError, ValueError) as exc:
        raise DownloadError(f"{label} is not a readable zip archive ({failure_reason(exc) if isinstance(exc, OSError) else exc})") from None


def _missing_member(label: str, member: str, names: set[str]) -> DownloadError:
    shown = sorted(names)[:5]
    more = f", ... ({len(names)} in all)" if len(names) > 5 else ""
    return DownloadError(f"{label} has no member {member} (members: {', '.join(shown) or 'none'}{more})")


def fetch_archive(
    url: str,
    dest: str | Path,
    expect_members: Iterable[str] = (),
    timeout: float = 60,
    hint: str = "",
    progress: bool = True,
    by_hand: str | None = None,
) -> Path:
    """Download a zip archive to ``dest`` atomically (no archive checksum exists to verify).

    Args:
        url: ``http://``, ``https://`` or ``file://`` URL of the archive.
        dest: destination path; its folder is created if needed. An existing
            file at ``dest`` is kept as it is if it is a readable zip listing
            ``expect_members`` (an earlier download or one placed by hand).
        expect_members: member names the archive must list; checked on the
            central directory only (fast), before ``dest`` is created.
        timeout: seconds allowed for connecting and for each read.
        hint: extra advice appended to the "download it by hand" message
            (e.g. the Snakemake option that takes a local archive).
        progress: draw pooch's progress bar (tqdm, bytes) on stderr while
            downloading over HTTP (see :func:`lagsplat.io.download.retrieve`).
        by_hand: replaces the whole "download it by hand" advice of the
            error messages (``hint`` is then ignored).

    Returns:
        ``dest`` as a :class:`~pathlib.Path`.

    Raises:
        DownloadError: one line: a network failure (``"cannot download <url>
            (<reason>); you appear to be offline: download <url> by hand and
            place it at <dest>..."``), an HTTP error, a file that is not a zip
            archive or lacks an expected member. Nothing is left at ``dest``
            (a file that was there before is never touched) and no temporary
            file survives.
    """
    dest = Path(dest)
    expect = list(expect_members)
    if dest.is_file():
        names = _members(dest, f"{dest} (already present)")
        missing = [m for m in expect if m not in names]
        if missing:
            raise _missing_member(f"{dest} (already present; delete it to download again)", missing[0], names)
        return dest
    if by_hand is None:
        by_hand = f"download {url} by hand and place it at {dest}" + (f", {hint}" if hint else "")
    tmp = _tmp_name(dest)
    try:
        retrieve(url, tmp, None, by_hand, timeout=timeout, progress=progress)  # no archive checksum exists
        names = _members(tmp, f"the file downloaded from {url}")
        for m in expect:
            if m not in names:
                raise _missing_member(f"the archive downloaded from {url}", m, names)
        os.replace(tmp, dest)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return dest


def extract_member(archive: str | Path, member: str, dest: str | Path, sha256: str) -> Path:
    """Extract ``member`` of the zip ``archive`` to ``dest`` and verify its SHA256, atomically.

    ``pooch.Unzip(members=[member])`` unpacks the member into a hidden
    temporary folder beside ``dest`` (zipfile checks its CRC-32), which is
    removed afterwards; only a member whose SHA256 matches is renamed onto
    ``dest``. The archive is only read.

    Args:
        archive: path of a local zip file.
        member: name inside the archive, e.g.
            ``processed_data/scr_dataset_raw_2seg_32x32_59fps.npz``.
        dest: destination file; its folder is created if needed.
        sha256: expected hex digest of the member (64 hex digits, any case).

    Returns:
        ``dest`` as a :class:`~pathlib.Path`.

    Raises:
        DownloadError: one line: archive missing or not a readable zip,
            member missing (the first members are listed), a corrupt member
            (CRC or decompression error), or ``"sha256 mismatch for member
            <member> of <archive>: expected X, got Y"``. Nothing is left at
            ``dest`` (unless a file was there before, which is not touched)
            and no temporary file survives.
        ValueError: if ``sha256`` is not 64 hex digits.
    """
    expected = check_digest(sha256)
    archive, dest = Path(archive), Path(dest)
    if not archive.is_file():
        raise DownloadError(f"archive {archive} not found (expected a zip file holding {member})")
    names = _members(archive, str(archive))
    if member not in names:
        raise _missing_member(str(archive), member, names)
    dest.parent.mkdir(parents=True, exist_ok=True)
    # absolute: pooch.Unzip joins a relative extract_dir onto the archive's folder
    unzipped = Path(tempfile.mkdtemp(prefix=f".{dest.name}.", suffix=".unzip", dir=dest.parent)).resolve()
    try:
        try:
            with quiet_pooch():
                pooch.Unzip(members=[member], extract_dir=str(unzipped))(str(archive.resolve()), "download", None)
        except (zipfile.BadZipFile, zlib.error, EOFError, ValueError, NotImplementedError) as exc:
            raise DownloadError(f"member {member} of {archive} is corrupt ({exc})") from None
        except OSError as exc:
            raise DownloadError(f"cannot extract {member} of {archive} to {dest} ({failure_reason(exc)})") from None
        out = unzipped / member
        if not out.is_file():
            raise DownloadError(f"member {member} of {archive} is not a file that unzips to its own name (a folder, or an unsafe path)")
        got = sha256_file(out)
        if got != expected:
            raise DownloadError(f"sha256 mismatch for member {member} of {archive}: expected {expected}, got {got}")
        os.replace(out, dest)
    finally:
        shutil.rmtree(unzipped, ignore_errors=True)
    return dest


def fetch_member(
    url: str,
    member: str,
    dest: str | Path,
    sha256: str,
    archive: str | Path | None = None,
    cache: str | Path | None = None,
    timeout: float = 60,
    hint: str = "",
    progress: bool = True,
) -> Path:
    """Make ``dest`` hold ``member`` of the zip at ``url``, verified by its SHA256.

    Order: (1) ``dest`` already holds the right bytes: return at once, nothing
    read or downloaded; (2) ``archive`` given: extract from that local file
    (never modified or deleted); (3) ``cache`` names an existing file: extract
    from it (an earlier download, or one placed there by hand); (4) download
    ``url`` to ``cache`` (or, without ``cache``, to a hidden temporary file
    beside ``dest``, deleted once the member is out) and extract.

    An archive downloaded by this call is deleted whenever extraction fails,
    so a wrong download never lingers; a pre-existing ``cache`` file that
    fails is kept and the error says so.

    Args:
        url: ``http(s)://`` or ``file://`` URL of the zip archive.
        member: name of the file inside the archive.
        dest: destination of the extracted member.
        sha256: expected hex digest of the member.
        archive: optional local copy of the archive (the user's download).
        cache: optional path where a downloaded archive is kept for later
            calls (e.g. the other members of the same record).
        timeout: seconds allowed for connecting and for each read.
        hint: extra advice for the offline message (how to pass a local archive).
        progress: draw a download progress bar on stderr (see :func:`fetch_archive`).

    Returns:
        ``dest`` as a :class:`~pathlib.Path`.

    Raises:
        DownloadError: one line (see :func:`fetch_archive` and
            :func:`extract_member`); offline, it says to download ``url`` by
            hand and where to put it, or where to place the extracted member
            and its SHA256.
        ValueError: if ``sha256`` is not 64 hex digits.
    """
    expected = check_digest(sha256)
    dest = Path(dest)
    if dest.is_file() and sha256_file(dest) == expected:
        return dest
    if archive is not None:
        return extract_member(archive, member, dest, expected)
    if cache is not None and Path(cache).is_file():
        try:
            return extract_member(cache, member, dest, expected)
        except DownloadError as exc:
            raise DownloadError(f"{exc} [cached archive {cache} kept; delete it to download again]") from None
    target = Path(cache) if cache is not None else _tmp_name(dest, ".zip.part")
    place = f"place it at {target}" if cache is not None else "give its path as the local archive"
    by_hand = f"download {url} by hand and {place}" + (f", {hint}" if hint else "")
    by_hand += f", or place its member {member} at {dest} (sha256 {expected})"
    try:
        fetch_archive(url, target, [member], timeout=timeout, progress=progress, by_hand=by_hand)
        extract_member(target, member, dest, expected)
    except BaseException:
        target.unlink(missing_ok=True)
        raise
    if cache is None:
        target.unlink(missing_ok=True)
    return dest


def main(argv: list[str] | None = None) -> int:
    """CLI (see the module docstring); returns the exit status (0 ok, 1 error, 2 usage)."""
    ap = argparse.ArgumentParser(prog="python -m lagsplat.io.zenodo", description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    a = sub.add_parser("archive", help="download a zip archive atomically and check the members it lists")
    a.add_argument("url")
    a.add_argument("dest")
    a.add_argument("--member", action="append", default=[], help="a member the archive must list (repeatable)")
    a.add_argument("--hint", default="", help="extra advice for the offline message")
    m = sub.add_parser("member", help="extract one member (from a local archive or a URL) and verify its SHA256")
    m.add_argument("source", help="local archive path, or URL of the archive")
    m.add_argument("member")
    m.add_argument("dest")
    m.add_argument("sha256")
    m.add_argument("--cache", default=None, help="with a URL: keep the downloaded archive here")
    m.add_argument("--hint", default="", help="extra advice for the offline message")
    try:
        args = ap.parse_args(sys.argv[1:] if argv is None else list(argv))
    except SystemExit as exc:
        return int(exc.code or 0) and 2
    try:
        if args.cmd == "archive":
            out = fetch_archive(args.url, args.dest, args.member, hint=args.hint)
        elif "://" in args.source:
            out = fetch_member(args.source, args.member, args.dest, args.sha256, cache=args.cache, hint=args.hint)
        else:
            out = extract_member(args.source, args.member, args.dest, args.sha256)
    except (DownloadError, ValueError, OSError) as exc:
        print(f"error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 1
    print(out)
    return 0


if __name__ == "__main__":  # pragma: no cover - exercised through a subprocess in tests
    sys.exit(main())
