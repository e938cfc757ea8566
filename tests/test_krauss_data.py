"""Soft-robot data rules: archive download, member extraction, SHA256, split, systems.

A tiny NPZ in the Krauss layout is zipped in ``tmp_path`` as
``processed_data/scr_dataset_raw_2seg_32x32_59fps.npz`` and fetched by
``file://`` URL, the way the real 4.5 GB Zenodo archive is fetched over https.
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from lagsplat.io.download import DownloadError, sha256_file
from lagsplat.io.zenodo import extract_member, fetch_archive, fetch_member

ROOT = Path(__file__).resolve().parents[1]
MEMBER = "processed_data/scr_dataset_raw_2seg_32x32_59fps.npz"
OTHER = "processed_data/scr_dataset_raw_1seg_32x32_59fps.npz"
UNREACHABLE = "http://127.0.0.1:9/processed_data.zip"  # discard port: connection refused
T = 60


def _krauss_npz(path: Path, n_chambers: int = 4, T: int = T, seed: int = 0) -> Path:
    """A tiny recording in the published layout: images (T,3,32,32) float32 multiples of 1/255, p1..pn (T,)."""
    rng = np.random.default_rng(seed)
    u8 = rng.integers(0, 256, size=(T, 3, 32, 32), dtype=np.uint8)
    arrays = {"images": u8.astype(np.float32) / np.float32(255.0)}
    for c in range(n_chambers):
        arrays[f"p{c + 1}"] = np.abs(np.sin(np.arange(T) * 0.1 * (c + 1))) * 0.9
    with open(path, "wb") as fh:
        np.savez_compressed(fh, **arrays)
    return path


@pytest.fixture()
def archive(tmp_path) -> tuple[Path, str, bytes]:
    """``(zip path, sha256 of the 2seg member, member bytes)``."""
    npz = _krauss_npz(tmp_path / "member.npz")
    other = _krauss_npz(tmp_path / "other.npz", n_chambers=2, seed=1)
    z = tmp_path / "remote" / "processed_data.zip"
    z.parent.mkdir()
    with zipfile.ZipFile(z, "w") as zf:
        zf.write(other, OTHER)
        zf.write(npz, MEMBER)
    data = npz.read_bytes()
    return z, hashlib.sha256(data).hexdigest(), data


def _listing(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir()) if folder.exists() else []


def test_fetch_member_by_file_url_then_no_op(archive, tmp_path):
    z, sha, data = archive
    dest = tmp_path / "raw" / "scr_dataset_raw_2seg_32x32_59fps.npz"
    out = fetch_member(z.as_uri(), MEMBER, dest, sha.upper(), progress=False)
    assert out == dest and dest.read_bytes() == data and sha256_file(dest) == sha
    assert _listing(dest.parent) == [dest.name]  # the downloaded archive and temporaries are gone
    z.unlink()  # a second call finds the verified file and touches nothing
    mtime = dest.stat().st_mtime_ns
    assert fetch_member(z.as_uri(), MEMBER, dest, sha, progress=False) == dest
    assert dest.stat().st_mtime_ns == mtime


def test_fetch_member_checksum_mismatch_leaves_nothing(archive, tmp_path):
    z, sha, _ = archive
    folder = tmp_path / "raw"
    wrong = "0" * 64
    with pytest.raises(DownloadError) as ei:
        fetch_member(z.as_uri(), MEMBER, folder / "x.npz", wrong, cache=folder / "processed_data.zip", progress=False)
    msg = str(ei.value)
    assert "\n" not in msg and msg.startswith(f"sha256 mismatch for member {MEMBER} of ")
    assert f"expected {wrong}, got {sha}" in msg
    assert _listing(folder) == []  # neither the member, nor the archive downloaded for it, nor a temporary


def test_fetch_member_missing_member(archive, tmp_path):
    z, sha, _ = archive
    folder = tmp_path / "raw"
    with pytest.raises(DownloadError) as ei:
        fetch_member(z.as_uri(), "processed_data/nope.npz", folder / "nope.npz", sha, progress=False)
    msg = str(ei.value)
    assert "has no member processed_data/nope.npz" in msg and MEMBER in msg and "\n" not in msg
    assert _listing(folder) == []


def test_fetch_member_corrupt_zip(tmp_path):
    bad = tmp_path / "remote" / "processed_data.zip"
    bad.parent.mkdir()
    bad.write_bytes(b"PK\x03\x04 this is not really a zip archive" * 10)
    folder = tmp_path / "raw"
    with pytest.raises(DownloadError) as ei:
        fetch_member(bad.as_uri(), MEMBER, folder / "x.npz", "a" * 64, cache=folder / "processed_data.zip", progress=False)
    assert "is not a readable zip archive" in str(ei.value) and "\n" not in str(ei.value)
    assert _listing(folder) == []


def test_corrupt_member_crc(archive, tmp_path):
    z, sha, _ = archive
    raw = bytearray(z.read_bytes())
    with zipfile.ZipFile(z) as zf:
        info = zf.getinfo(MEMBER)
    start = info.header_offset + 30 + len(info.filename.encode()) + len(info.extra)
    raw[start + info.compress_size // 2] ^= 0xFF  # flip one byte of the stored member
    bad = tmp_path / "bad.zip"
    bad.write_bytes(bytes(raw))
    folder = tmp_path / "raw"
    with pytest.raises(DownloadError) as ei:
        extract_member(bad, MEMBER, folder / "x.npz", sha)
    assert f"member {MEMBER} of {bad} is corrupt (Bad CRC-32" in str(ei.value)
    assert _listing(folder) == []


def test_extract_member_takes_that_member_only(archive, tmp_path):
    """pooch.Unzip matches members by prefix: a longer name beside the member must neither be taken nor left."""
    z, sha, data = archive
    both = tmp_path / "both.zip"
    with zipfile.ZipFile(z) as src, zipfile.ZipFile(both, "w") as zf:
        zf.writestr(MEMBER + ".old", b"an older version")
        zf.writestr(MEMBER, src.read(MEMBER))
    dest = tmp_path / "raw" / "x.npz"
    assert extract_member(both, MEMBER, dest, sha) == dest and dest.read_bytes() == data
    assert _listing(dest.parent) == ["x.npz"]  # the temporary folder is gone with the other file


def test_relative_paths(archive, tmp_path, monkeypatch):
    """Archive, cache and destination given relative to the working folder (as the CLI gets them)."""
    z, sha, data = archive
    monkeypatch.chdir(tmp_path)
    assert fetch_member(z.as_uri(), MEMBER, Path("raw/a.npz"), sha, progress=False) == Path("raw/a.npz")
    assert extract_member(Path("remote/processed_data.zip"), MEMBER, Path("raw/b.npz"), sha) == Path("raw/b.npz")
    assert (tmp_path / "raw" / "a.npz").read_bytes() == data == (tmp_path / "raw" / "b.npz").read_bytes()
    assert _listing(tmp_path / "raw") == ["a.npz", "b.npz"]


def test_fetch_member_offline_says_what_and_where(tmp_path):
    dest = tmp_path / "raw" / "scr_dataset_raw_2seg_32x32_59fps.npz"
    sha = "dd2d8508cffb30284e46a375fc662d168c1f50b759445a4eaf601734293e82bc"
    with pytest.raises(DownloadError) as ei:
        fetch_member(UNREACHABLE, MEMBER, dest, sha, cache=tmp_path / "raw" / "processed_data.zip", timeout=5, progress=False)
    msg = str(ei.value)
    assert "\n" not in msg and msg.startswith(f"cannot download {UNREACHABLE} (") and "you appear to be offline" in msg
    assert f"download {UNREACHABLE} by hand and place it at {tmp_path / 'raw' / 'processed_data.zip'}" in msg
    assert f"place its member {MEMBER} at {dest} (sha256 {sha})" in msg
    assert _listing(dest.parent) == []


def test_local_archive_is_used_and_left_alone(archive, tmp_path):
    z, sha, data = archive
    before = z.read_bytes()
    dest = tmp_path / "raw" / "m.npz"
    assert fetch_member(UNREACHABLE, MEMBER, dest, sha, archive=z, progress=False) == dest  # no network needed
    assert dest.read_bytes() == data and z.read_bytes() == before
    with pytest.raises(DownloadError, match="sha256 mismatch"):
        fetch_member(UNREACHABLE, MEMBER, tmp_path / "raw" / "n.npz", "1" * 64, archive=z, progress=False)
    assert z.exists() and _listing(tmp_path / "raw") == ["m.npz"]  # the user's archive is never deleted
    with pytest.raises(DownloadError, match="not found"):
        fetch_member(UNREACHABLE, MEMBER, tmp_path / "raw" / "o.npz", sha, archive=tmp_path / "nowhere.zip")


def test_cache_serves_the_second_member(archive, tmp_path):
    z, sha, _ = archive
    cache = tmp_path / "raw" / "processed_data.zip"
    fetch_member(z.as_uri(), MEMBER, tmp_path / "raw" / "a.npz", sha, cache=cache, progress=False)
    assert cache.is_file()  # kept for the other robot
    sha_other = hashlib.sha256(zipfile.ZipFile(z).read(OTHER)).hexdigest()
    fetch_member(UNREACHABLE, OTHER, tmp_path / "raw" / "b.npz", sha_other, cache=cache, progress=False)
    assert sha256_file(tmp_path / "raw" / "b.npz") == sha_other


def test_fetch_member_over_http_downloads_the_archive_once(archive, http_folder, tmp_path):
    """A real HTTP download (pooch's HTTPDownloader): the archive is fetched once, cached, and serves both members."""
    z, sha, data = archive
    root, base, gets = http_folder
    (root / z.name).write_bytes(z.read_bytes())
    url, raw = f"{base}/{z.name}", tmp_path / "raw"
    cache = raw / "processed_data.zip"
    assert fetch_member(url, MEMBER, raw / "a.npz", sha, cache=cache, progress=False) == raw / "a.npz"
    assert (raw / "a.npz").read_bytes() == data and cache.read_bytes() == z.read_bytes()
    sha_other = hashlib.sha256(zipfile.ZipFile(z).read(OTHER)).hexdigest()
    fetch_member(url, OTHER, raw / "b.npz", sha_other, cache=cache, progress=False)
    fetch_member(url, MEMBER, raw / "a.npz", sha, cache=cache, progress=False)  # already verified in place
    assert gets == [f"/{z.name}"] and sha256_file(raw / "b.npz") == sha_other
    assert _listing(raw) == ["a.npz", "b.npz", "processed_data.zip"]  # no temporaries
    with pytest.raises(DownloadError) as ei:
        fetch_member(f"{base}/gone.zip", MEMBER, raw / "c.npz", sha, progress=False)
    assert str(ei.value).startswith(f"cannot download {base}/gone.zip (HTTP 404 ") and "offline" not in str(ei.value)
    assert _listing(raw) == ["a.npz", "b.npz", "processed_data.zip"]


def test_fetch_archive_checks_members(archive, tmp_path):
    z, _, _ = archive
    dest = tmp_path / "raw" / "processed_data.zip"
    with pytest.raises(DownloadError, match="has no member processed_data/missing.npz"):
        fetch_archive(z.as_uri(), dest, [MEMBER, "processed_data/missing.npz"], progress=False)
    assert _listing(dest.parent) == []
    assert fetch_archive(z.as_uri(), dest, [MEMBER, OTHER], progress=False) == dest
    assert dest.read_bytes() == z.read_bytes()


def _run(args: list[str], timeout: int = 120) -> subprocess.CompletedProcess:
    env = dict(os.environ, OMP_NUM_THREADS="1")
    return subprocess.run(args, cwd=ROOT, capture_output=True, text=True, timeout=timeout, env=env)


def test_archive_cli_offline_prints_one_line(tmp_path):
    dest = tmp_path / "processed_data.zip"
    r = _run([sys.executable, "-m", "lagsplat.io.zenodo", "archive", UNREACHABLE, str(dest), "--member", MEMBER, "--hint", "or pass a local copy"])
    assert r.returncode == 1 and "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "offline" in lines[0] and str(dest) in lines[0] and "or pass a local copy" in lines[0]
    assert not dest.exists() and _listing(tmp_path) == []


def test_download_stage_extracts_and_ingest_splits(archive, tmp_path):
    """``python -m lagsplat download system=krauss_2seg download.archive=...`` then ingest: the published split."""
    z, sha, data = archive
    raw = tmp_path / "raw"
    base = [sys.executable, "-m", "lagsplat"]
    # the real checksum: the tiny member must be refused, in one line, leaving nothing
    r = _run(base + ["download", "system=krauss_2seg", f"raw_dir={raw}", f"download.archive={z}"])
    assert r.returncode == 1 and len(r.stderr.strip().splitlines()) == 1 and "sha256 mismatch" in r.stderr
    assert _listing(raw) == []
    r = _run(base + ["download", "system=krauss_2seg", f"raw_dir={raw}", f"download.archive={z}", f"system.source.sha256={sha}"])
    assert r.returncode == 0, r.stderr
    dest = raw / "scr_dataset_raw_2seg_32x32_59fps.npz"
    assert dest.read_bytes() == data

    from lagsplat.cli import compose
    from lagsplat.ingest import ingest

    cfg = compose(["system=krauss_2seg", f"raw_dir={raw}"])
    clip = ingest(cfg.system)
    assert clip.n_frames == T and len(clip.train_idx) == int(0.8 * T) == 48
    assert np.array_equal(clip.train_idx, np.arange(48)) and np.array_equal(clip.held_out_idx, np.arange(48, T))
    assert clip.dt == pytest.approx(1001 / 60000, rel=1e-12)
    assert clip.u_names == ["p1", "p2", "p3", "p4"]
    with np.load(dest) as f:
        assert np.array_equal(clip.u[:, 2], f["p3"].astype(np.float32))  # pressures as stored
        assert np.array_equal(clip.images, np.rint(np.moveaxis(f["images"], 1, -1) * 255).astype(np.uint8))


def test_systems_compose():
    from lagsplat.cli import compose

    for name, d, n_u, data in [("krauss_1seg", 2, 2, "real"), ("krauss_2seg", 4, 4, "real"), ("krauss_2seg_synth", 4, 4, "surrogate"), ("krauss_1seg_synth", 2, 2, "surrogate")]:
        c = compose([f"system={name}"])
        assert c.system.name == name and c.system.d == d and len(c.system.source.actuation) == n_u
        assert c.system.data == data and c.system.protocol == "krauss"
        assert c.stage2.potential == "invex" and c.stage2.mass == "learned" and c.stage1.n_gaussians == 2048
        assert c.system.split.train_fraction == 0.8 and c.system.source.dt == 1001 / 60000
    assert compose(["system=krauss_2seg"]).system.source.sha256.startswith("dd2d8508")
    assert compose(["system=krauss_1seg"]).system.source.sha256.startswith("3e576950")


@pytest.mark.parametrize("source,jobs", [
    ("zenodo", {"krauss_archive", "krauss_extract", "ingest", "stage1", "chart", "stage2", "stage2_variant", "evaluate", "evaluate_variant", "krauss_table"}),
    ("synthetic", {"krauss_synth", "ingest", "stage1", "chart", "stage2", "stage2_variant", "evaluate", "evaluate_variant", "krauss_table"}),
])
def test_snakemake_dry_run_shows_the_whole_chain(tmp_path, source, jobs):
    r = _run(["snakemake", "-n", "-p", "--nolock", "-c1", f"{tmp_path}/res/tables/krauss.tex", "--config",
              f"results_dir={tmp_path}/res", f"raw_dir={tmp_path}/raw", f"krauss_source={source}"])
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    lines = r.stdout.splitlines()
    stats = lines[lines.index("Job stats:") + 3 :]  # after the header and the dashes
    planned = {ln.split()[0] for ln in stats[: next(i for i, ln in enumerate(stats) if ln.startswith("total"))]}
    assert planned == jobs
    sfx = "" if source == "zenodo" else "_synth"
    for s in ("krauss_1seg", "krauss_2seg"):
        assert f"{tmp_path}/res/{s}{sfx}/metrics.json" in r.stdout
    assert f"{tmp_path}/res/krauss_2seg{sfx}/variants/mass_decoder/metrics.json" in r.stdout
    # the table job runs in the two-segment configuration, so --config overrides for the robots compose there too
    assert f"python -m lagsplat krauss_table system=krauss_2seg{sfx} " in r.stdout


def test_snakemake_rejects_unknown_source(tmp_path):
    r = _run(["snakemake", "-n", "--nolock", "-c1", f"{tmp_path}/tables/krauss.tex", "--config", f"results_dir={tmp_path}", "krauss_source=nope"])
    out = r.stdout + r.stderr
    assert r.returncode != 0 and "'nope' is not one of ['zenodo', 'synthetic']" in out and "krauss_source" in out  # the config schema
