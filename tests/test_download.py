"""Tests of lagsplat.io.download: checksum-verified, atomic fetching and its CLI."""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
from pathlib import Path

import pytest

from lagsplat.io.download import DownloadError, fetch, sha256_file

REPO = Path(__file__).resolve().parents[1]
PAYLOAD = b"lagsplat test payload\n" * 1000
PAYLOAD_SHA = hashlib.sha256(PAYLOAD).hexdigest()
UNREACHABLE = "http://127.0.0.1:9/nothing"  # discard port: connection refused


@pytest.fixture()
def src(tmp_path) -> Path:
    p = tmp_path / "remote" / "file.bin"
    p.parent.mkdir()
    p.write_bytes(PAYLOAD)
    return p


@pytest.fixture()
def http_server(http_folder):
    """A local HTTP server serving ``file.bin`` (``PAYLOAD``): ``(base_url, gets)``."""
    root, url, gets = http_folder
    (root / "file.bin").write_bytes(PAYLOAD)
    return url, gets


def _names(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def test_sha256_file(tmp_path):
    p = tmp_path / "x"
    p.write_bytes(b"abc")
    assert sha256_file(p) == "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"


def test_fetch_file_url(src, tmp_path):
    dest = tmp_path / "data" / "raw" / "file.bin"
    out = fetch(src.as_uri(), dest, PAYLOAD_SHA.upper())
    assert out == dest and dest.read_bytes() == PAYLOAD
    assert sorted(p.name for p in dest.parent.iterdir()) == ["file.bin"]
    src.unlink()  # already present with the right hash: no download needed
    assert fetch(src.as_uri(), dest, PAYLOAD_SHA) == dest


def test_fetch_relative_destination(src, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert fetch(src.as_uri(), "raw/file.bin", PAYLOAD_SHA) == Path("raw/file.bin")
    assert (tmp_path / "raw" / "file.bin").read_bytes() == PAYLOAD and _names(tmp_path / "raw") == ["file.bin"]


def test_fetch_replaces_stale_file(src, tmp_path):
    dest = tmp_path / "file.bin"
    dest.write_bytes(b"old version")
    fetch(src.as_uri(), dest, PAYLOAD_SHA)
    assert dest.read_bytes() == PAYLOAD


def test_fetch_http(http_server, tmp_path):
    base, gets = http_server
    dest = tmp_path / "d" / "file.bin"
    fetch(f"{base}/file.bin", dest, PAYLOAD_SHA)
    assert sha256_file(dest) == PAYLOAD_SHA
    with pytest.raises(DownloadError) as ei:
        fetch(f"{base}/missing.bin", tmp_path / "d" / "m.bin", PAYLOAD_SHA)
    msg = str(ei.value)
    assert "HTTP 404" in msg and "offline" not in msg and str(tmp_path / "d" / "m.bin") in msg
    assert sorted(p.name for p in (tmp_path / "d").iterdir()) == ["file.bin"]
    assert gets == ["/file.bin", "/missing.bin"]


def test_fetch_http_cached_file_is_not_fetched_twice(http_server, tmp_path):
    base, gets = http_server
    dest = tmp_path / "d" / "file.bin"
    assert fetch(f"{base}/file.bin", dest, PAYLOAD_SHA) == dest
    mtime = dest.stat().st_mtime_ns
    assert fetch(f"{base}/file.bin", dest, PAYLOAD_SHA) == dest  # verified in place: no second request
    assert gets == ["/file.bin"] and dest.stat().st_mtime_ns == mtime
    dest.write_bytes(b"stale")  # a wrong local copy is fetched again and replaced
    fetch(f"{base}/file.bin", dest, PAYLOAD_SHA)
    assert gets == ["/file.bin", "/file.bin"] and dest.read_bytes() == PAYLOAD


def test_fetch_http_checksum_mismatch_names_the_file(http_server, tmp_path):
    base, gets = http_server
    folder = tmp_path / "out"
    wrong = "f" * 64
    with pytest.raises(DownloadError) as ei:
        fetch(f"{base}/file.bin", folder / "file.bin", wrong)
    assert str(ei.value) == f"sha256 mismatch for {base}/file.bin: expected {wrong}, got {PAYLOAD_SHA}"
    assert gets == ["/file.bin"] and list(folder.iterdir()) == []  # downloaded, refused, nothing kept


def test_fetch_checksum_mismatch_leaves_nothing(src, tmp_path):
    folder = tmp_path / "out"
    dest = folder / "file.bin"
    wrong = "0" * 64
    with pytest.raises(DownloadError) as ei:
        fetch(src.as_uri(), dest, wrong)
    assert str(ei.value) == f"sha256 mismatch for {src.as_uri()}: expected {wrong}, got {PAYLOAD_SHA}"
    assert not dest.exists()
    assert list(folder.iterdir()) == []  # no temporary file left behind


def test_fetch_offline_message(tmp_path):
    dest = tmp_path / "raw" / "clip.webm"
    with pytest.raises(DownloadError) as ei:
        fetch(UNREACHABLE, dest, PAYLOAD_SHA, timeout=5)
    msg = str(ei.value)
    assert msg.startswith(f"cannot download {UNREACHABLE} (")
    assert "you appear to be offline" in msg and str(dest) in msg and PAYLOAD_SHA in msg
    assert "\n" not in msg
    assert not dest.exists() and list(dest.parent.iterdir()) == []


def test_fetch_rejects_bad_digest(src, tmp_path):
    with pytest.raises(ValueError, match="64 hex"):
        fetch(src.as_uri(), tmp_path / "x", "abc")


def test_fetch_missing_local_file_and_unknown_scheme(tmp_path):
    dest = tmp_path / "raw" / "x.bin"
    missing = (tmp_path / "nowhere.bin").as_uri()
    with pytest.raises(DownloadError) as ei:
        fetch(missing, dest, PAYLOAD_SHA)
    assert str(ei.value) == (f"cannot download {missing} (No such file or directory); "
                             f"download it by hand and place it at {dest} (sha256 {PAYLOAD_SHA})")
    with pytest.raises(DownloadError, match=r"^cannot download gopher://h/x \(unsupported URL scheme 'gopher'"):
        fetch("gopher://h/x", dest, PAYLOAD_SHA)
    assert list(dest.parent.iterdir()) == []


def _cli(*args: str) -> subprocess.CompletedProcess:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    return subprocess.run([sys.executable, "-m", "lagsplat.io.download", *args], capture_output=True, text=True,
                          env=env, cwd=REPO, timeout=60)


def test_cli_failure_prints_one_line(tmp_path):
    dest = tmp_path / "clip.webm"
    r = _cli(UNREACHABLE, str(dest), PAYLOAD_SHA)
    assert r.returncode == 1
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "offline" in lines[0] and str(dest) in lines[0]
    assert "Traceback" not in r.stderr and not dest.exists()


def test_cli_success(src, tmp_path):
    dest = tmp_path / "ok.bin"
    r = _cli(src.as_uri(), str(dest), PAYLOAD_SHA)
    assert r.returncode == 0, r.stderr
    assert dest.read_bytes() == PAYLOAD and r.stdout.strip() == str(dest)
