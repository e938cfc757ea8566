"""Several recordings of one system: ingest of ``system.sources``,
episodes in the clip, and Stage-2 windows that never cross a recording."""

from __future__ import annotations

import numpy as np
import pytest

from lagsplat.io.clip import HELD_OUT, TRAIN, ClipError, concatenate_clips, load_clip, save_clip
from lagsplat.ingest import ingest


def _npz(path, n, value, p=None):
    images = np.full((n, 8, 10, 3), value, np.uint8)
    extra = {} if p is None else {"p1": np.full(n, p, np.float32)}
    np.savez(path, images=images, **extra)
    return path


def test_sources_become_episodes_with_whole_recordings_held_out(tmp_path):
    files = [_npz(tmp_path / f"r{i}.npz", n, 10 * i, p=0.1 * i) for i, n in enumerate([12, 15, 9])]
    cfg = {
        "name": "bag",
        "sources": [
            {"path": str(files[0]), "fps": 30.0, "actuation": ["p1"]},
            {"path": str(files[1]), "fps": 30.0, "actuation": ["p1"], "frames": [2, None]},
            {"path": str(files[2]), "fps": 30.0, "actuation": ["p1"], "held_out": True},
        ],
        "resize": [5, 4],
    }
    clip = ingest(cfg)
    assert clip.n_frames == 12 + 13 + 9
    np.testing.assert_array_equal(clip.episode, np.repeat([0, 1, 2], [12, 13, 9]))
    np.testing.assert_array_equal(clip.split, np.repeat([TRAIN, TRAIN, HELD_OUT], [12, 13, 9]))
    assert clip.images.shape[1:] == (4, 5, 3)
    assert np.all(np.diff(clip.t) > 0)
    np.testing.assert_allclose(clip.u[12:, 0], np.repeat([0.1, 0.2], [13, 9]), rtol=1e-6)
    assert [len(s) for s in clip.segments(TRAIN)] == [12, 13]
    assert clip.meta["split"] == {"kind": "episodes", "held_out": [2]}
    # the episode index survives the file
    path = save_clip(tmp_path / "clip.npz", clip)
    np.testing.assert_array_equal(load_clip(path).episode, clip.episode)


def test_sources_need_a_held_out_and_a_training_recording(tmp_path):
    f = _npz(tmp_path / "a.npz", 6, 0)
    with pytest.raises(ClipError, match="at least one training and one held-out"):
        ingest({"name": "bag", "sources": [{"path": str(f), "fps": 30.0}, {"path": str(f), "fps": 30.0}]})
    with pytest.raises(ClipError, match="sources\\[1\\]"):
        ingest({"name": "bag", "sources": [{"path": str(f), "fps": 30.0}, "oops"]})


def test_missing_recording_is_named(tmp_path):
    f = _npz(tmp_path / "a.npz", 6, 0)
    with pytest.raises(ClipError, match="nope.npz"):
        ingest({"name": "bag", "sources": [{"path": str(f), "fps": 30.0}, {"path": str(tmp_path / "nope.npz"), "fps": 30.0, "held_out": True}]})


def test_recordings_of_different_size_do_not_concatenate(tmp_path):
    a = ingest({"name": "a", "source": {"path": str(_npz(tmp_path / "a.npz", 6, 0)), "fps": 30.0}, "split": {"train_fraction": 1.0}})
    b = ingest({"name": "b", "source": {"path": str(_npz(tmp_path / "b.npz", 6, 0)), "fps": 30.0}, "split": {"train_fraction": 1.0}, "resize": [4, 4]})
    with pytest.raises(ClipError, match="recording 1 has frames"):
        concatenate_clips([a, b], [False, True])
