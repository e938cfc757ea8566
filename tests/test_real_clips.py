"""The real-clip test set (benchmarks/real_clips): a well-formed manifest, intact files, and reproducible references."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("real_clips", ROOT / "benchmarks" / "real_clips.py")
rc = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(rc)

KEYS = {"name", "file", "source_repo", "source_commit", "source_path", "source_url", "sha256", "licence", "derived", "fps",
        "frames", "what", "nuisances", "reference_hz", "reference_method", "reference_periods", "split"}  # fmt: skip
#: Cheap clips whose reference the test re-measures (short, small frames).
CHEAP = ["pendulum_drag", "oscillating_cart_short", "spring_wars_short", "lab_spring"]


@pytest.fixture(scope="module")
def manifest() -> list[dict]:
    return rc.load_manifest()


def test_manifest_well_formed(manifest):
    names = [e["name"] for e in manifest]
    assert len(names) == len(set(names)) >= 12
    for e in manifest:
        assert KEYS <= e.keys(), (e["name"], KEYS - e.keys())
        assert len(e["source_commit"]) == 40 and all(c in "0123456789abcdef" for c in e["source_commit"])
        assert e["source_url"] == f"https://raw.githubusercontent.com/{e['source_repo']}/{e['source_commit']}/{e['source_path']}"
        assert e["licence"].strip(), e["name"]
        assert e["split"] in ("test", "tune")
        start, stop = e["frames"]
        assert start >= 0 and (stop is None or stop > start)
        assert e["fps"] > 0 and e["reference_hz"] > 0 and math.isfinite(e["reference_hz"])
        assert e.get("turning_frames") or e.get("reference_track") or e.get("reference_kymograph"), e["name"]


def test_files_present_and_intact(manifest):
    for e in manifest:
        path = rc.clip_path(e)
        assert path.is_file(), path
        assert rc.sha256(path) == e["sha256"], e["name"]


def test_splits(manifest):
    for split in ("test", "tune"):
        assert sum(e["split"] == split for e in manifest) >= 6
    by_recording: dict[str, set[str]] = {}
    for e in manifest:
        by_recording.setdefault(e.get("recording", e["name"]), set()).add(e["split"])
    assert all(len(s) == 1 for s in by_recording.values()), "a recording's entries must share a split"


@pytest.mark.parametrize("name", CHEAP)
def test_reference_reproduces(manifest, name):
    entry = next(e for e in manifest if e["name"] == name)
    r = rc.measure_reference(entry)
    assert abs(r["hz"] - entry["reference_hz"]) <= 0.01 * entry["reference_hz"], (name, r["hz"], entry["reference_hz"])


def test_kymograph_frequency_reads_a_blurred_vertical_oscillation():
    fps, f = 60.0, 0.9
    t = np.arange(600) / fps
    frames = np.full((len(t), 120, 40), 200.0, np.float32)
    rows = np.arange(120)[None, :]
    bottom = 60 + 30 * np.sin(2 * np.pi * f * t)[:, None]  # the object's lowest point, px
    frames[:] -= 120.0 * ((rows <= bottom) & (rows >= bottom - 15))[:, :, None]  # a dark block hanging down to it
    hz, periods, y = rc.kymograph_frequency(frames, [10, 30], [0, 120], 25.0, 20.0, 30, fps)
    assert periods >= 7 and abs(hz - f) <= 0.01 * f
    assert np.nanmax(y) == pytest.approx(90, abs=1)
